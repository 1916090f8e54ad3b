//! `m1cs geometry` (alias `layout`): a layout's segments, actuators, edges and sensors, the
//! neighbour histogram, and a map of the segments coloured by their number of neighbours.

use clap::Args;

use crate::plot;

/// `m1cs geometry`.
#[derive(Args, Debug)]
pub struct GeometryArgs {
    /// Mirror layout (keck, tmt, elt) or a JSON file of segment centres.
    #[arg(long, default_value = m1::aperture::layout::DEFAULT_LAYOUT)]
    pub layout: String,
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
    /// Map PNG of the segments coloured by their number of neighbours.
    #[arg(long)]
    pub plot: Option<String>,
}

/// Runs `m1cs geometry`.
pub fn geometry(a: &GeometryArgs) -> Result<(), String> {
    let l = super::load_layout(&a.layout)?;
    let hist = l.neighbour_histogram();
    if let Some(p) = &a.plot {
        let degree: Vec<f64> = (0..l.n_segments())
            .map(|i| l.neighbours(i).len() as f64)
            .collect();
        plot::mirror_map(
            p,
            &l,
            &degree,
            &format!("{}: neighbours per segment", l.name),
            "neighbours",
        )
        .map_err(|e| e.to_string())?;
    }
    if a.json {
        let out = serde_json::json!({
            "layout": l.name,
            "segments": l.n_segments(),
            "actuators": l.n_actuators(),
            "edges": l.n_edges(),
            "sensors": l.n_sensors(),
            "neighbours": hist,
            "circumradius_m": l.circumradius,
            "gap_m": l.gap,
            "pitch_m": l.pitch(),
        });
        println!("{out}");
    } else {
        println!(
            "{}: {} segments, {} actuators, {} shared edges, {} edge sensors; pitch {:.5} m",
            l.name,
            l.n_segments(),
            l.n_actuators(),
            l.n_edges(),
            l.n_sensors(),
            l.pitch()
        );
        for (k, n) in hist {
            println!("  {n:>4} segments with {k} neighbours");
        }
    }
    Ok(())
}
