//! Wind loads on the segments (von Karman pressure screens, frozen flow).
