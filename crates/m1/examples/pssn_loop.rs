//! Times `Pssn::pssn_ptt` on TMT: the best of blocks of 100 evaluations of one segment state,
//! for profiling and for the choice between the OTF's two methods.
//!
//! `cargo run --release -p m1 --example pssn_loop -- [single|double] [corr|tran] [evaluations]
//! [r0 (m, at 500 nm)] [samples]` (defaults: single corr 2000 0.2 256).
#![allow(clippy::unwrap_used)]
use m1::aperture::layout::Layout;
use m1::optics::pssn::{OtfMethod, Pssn, PssnParams, PssnPrecision};
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let single = args.get(1).map(|s| s == "single").unwrap_or(true);
    let corr = args.get(2).map(|s| s == "corr").unwrap_or(true);
    let iters: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(2000);
    let layout = Layout::tmt();
    let p = if single {
        PssnPrecision::Single
    } else {
        PssnPrecision::Double
    };
    let m = if corr {
        OtfMethod::Correlation
    } else {
        OtfMethod::Transforms
    };
    let r0: f64 = args.get(4).and_then(|s| s.parse().ok()).unwrap_or(0.2);
    let samples: usize = args.get(5).and_then(|s| s.parse().ok()).unwrap_or(256);
    let params = PssnParams {
        r0,
        samples,
        ..PssnParams::default()
    };
    let pssn = Pssn::with_method(&layout, params, p, Some(m)).unwrap();
    print!(
        "rows {} P {} M {}: ",
        pssn.otf_lag_rows(),
        pssn.row_fft_size(),
        pssn.fft_size()
    );
    let ptt: Vec<[f64; 3]> = (0..layout.n_segments())
        .map(|s| {
            let f = s as f64;
            [
                1e-8 * (0.3 * f).sin(),
                1e-8 * (0.7 * f).cos(),
                1e-8 * (1.3 * f).sin(),
            ]
        })
        .collect();
    let mut best = f64::INFINITY;
    let mut acc = 0.0;
    for _ in 0..iters / 100 {
        let t = std::time::Instant::now();
        for _ in 0..100 {
            acc += pssn.pssn_ptt(&ptt).unwrap();
        }
        best = best.min(t.elapsed().as_secs_f64() / 100.0);
    }
    println!("{:.1} us per evaluation (best block) {acc}", best * 1e6);
}
