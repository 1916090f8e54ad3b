//! Model wiring of the `wind` FMU: wind loads on the segments from frozen-flow von Karman pressure screens.
