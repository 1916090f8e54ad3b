//! `m1cs cache`: the on-disk cache of computed arrays (the structure's modes, the wind's
//! tables; `m1::linalg::cache`): where it is, what it holds, and `--clear`.

use clap::Args;
use serde_json::json;

/// `m1cs cache`.
#[derive(Args, Debug)]
pub struct CacheArgs {
    /// Remove every entry.
    #[arg(long)]
    pub clear: bool,
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
}

/// Runs `m1cs cache`.
pub fn cache(a: &CacheArgs) -> Result<(), String> {
    let store = m1::linalg::cache::Store::from_env();
    let Some(dir) = store.dir().map(std::path::Path::to_path_buf) else {
        if a.json {
            println!("{}", json!({"dir": null, "entries": []}));
        } else {
            println!(
                "the cache is off (M1CS_CACHE=off, or none of M1CS_CACHE_DIR, XDG_CACHE_HOME, \
                 HOME is set)"
            );
        }
        return Ok(());
    };
    if a.clear {
        let (n, bytes) = store
            .clear()
            .map_err(|e| format!("{}: {e}", dir.display()))?;
        if a.json {
            println!(
                "{}",
                json!({"dir": dir.display().to_string(), "removed": n, "bytes": bytes})
            );
        } else {
            println!(
                "{}: removed {n} entries ({:.1} MB)",
                dir.display(),
                bytes as f64 / 1e6
            );
        }
        return Ok(());
    }
    let entries = store.entries();
    let total: u64 = entries.iter().map(|e| e.1).sum();
    if a.json {
        let list: Vec<_> = entries
            .iter()
            .map(|(p, s)| {
                json!({
                    "file": p.file_name().map(|n| n.to_string_lossy().into_owned()),
                    "bytes": s,
                })
            })
            .collect();
        println!(
            "{}",
            json!({"dir": dir.display().to_string(), "entries": list, "bytes": total})
        );
        return Ok(());
    }
    println!(
        "{}: {} entries, {:.1} MB (M1CS_CACHE_DIR moves it, M1CS_CACHE=off turns it off, \
         --clear empties it)",
        dir.display(),
        entries.len(),
        total as f64 / 1e6
    );
    for (p, s) in &entries {
        println!(
            "  {:>8.1} MB  {}",
            *s as f64 / 1e6,
            p.file_name()
                .map_or_else(String::new, |n| n.to_string_lossy().into_owned())
        );
    }
    Ok(())
}
