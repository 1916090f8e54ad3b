//! Checks of hand-written documentation against the variable table, so that a module's table of
//! signals cannot drift from the variables it describes.
//!
//! A wiring crate's module documentation lists its inputs and outputs as a Markdown table,
//!
//! ```text
//! | variable | causality | size | unit |
//! |---|---|---|---|
//! | `u` | input | na | m |
//! | `y` | output (no direct dependency on inputs) | na | m |
//! ```
//!
//! and its unit tests call [`check_signal_table`] on it: the rows must be the table's inputs and
//! outputs, in the table's order, each with its causality, its size (a number, or a symbol the
//! caller resolves, such as `na` for 3 x segments) and its unit (a variable without a declared
//! unit, such as the mixed-unit `w`, may say anything there); "no direct dependency on inputs"
//! is allowed only on an output that has none.

use crate::variables::{Causality, Dependencies, VariableTable};

/// Checks the first Markdown table of `doc` whose header starts with `| variable |` against
/// the inputs and outputs of `table`; `size` resolves the size column's symbols (numbers are
/// read as such).
///
/// # Errors
/// Every disagreement, one per line.
pub fn check_signal_table(
    doc: &str,
    table: &VariableTable,
    size: impl Fn(&str) -> Option<usize>,
) -> Result<(), String> {
    let rows: Vec<Vec<String>> = doc
        .lines()
        .map(|l| l.trim_start_matches("//!").trim())
        .skip_while(|l| !l.starts_with("| variable |"))
        .skip(2)
        .take_while(|l| l.starts_with('|'))
        .map(|l| {
            l.trim_matches('|')
                .split('|')
                .map(|c| c.trim().to_string())
                .collect()
        })
        .collect();
    let signals: Vec<_> = table
        .variables()
        .iter()
        .filter(|v| matches!(v.causality, Causality::Input | Causality::Output))
        .collect();
    let mut errors = Vec::new();
    let documented: Vec<String> = rows
        .iter()
        .map(|r| {
            r.first()
                .map(|c| c.trim_matches('`').to_string())
                .unwrap_or_default()
        })
        .collect();
    let declared: Vec<String> = signals.iter().map(|v| v.name.clone()).collect();
    if documented != declared {
        errors.push(format!(
            "the documented signals {documented:?} are not the table's inputs and outputs \
             {declared:?} (in that order)"
        ));
    }
    for (row, v) in rows.iter().zip(&signals) {
        let [_, causality, sz, unit] = row.as_slice() else {
            errors.push(format!("{}: expected 4 columns, found {row:?}", v.name));
            continue;
        };
        if !causality.starts_with(v.causality.xml()) {
            errors.push(format!(
                "{}: documented as {causality}, declared {}",
                v.name,
                v.causality.xml()
            ));
        }
        if causality.contains("no direct dependency") && v.dependencies != Dependencies::None {
            errors.push(format!(
                "{}: documented without direct dependency, declared with {:?}",
                v.name, v.dependencies
            ));
        }
        match sz.parse::<usize>().ok().or_else(|| size(sz)) {
            Some(n) if n == v.len => {}
            Some(n) => errors.push(format!(
                "{}: documented size {sz} = {n}, declared {}",
                v.name, v.len
            )),
            None => errors.push(format!("{}: unknown size {sz:?}", v.name)),
        }
        if let Some(u) = &v.unit
            && u != unit
        {
            errors.push(format!(
                "{}: documented in {unit:?}, declared in {u:?}",
                v.name
            ));
        }
    }
    if errors.is_empty() {
        Ok(())
    } else {
        Err(errors.join("\n"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::variables::TableBuilder as T;

    fn table() -> VariableTable {
        let mut b = T::new();
        b.add_real(T::real("k").parameter().start(1.0).describe("Gain"));
        b.add_real(
            T::real("u")
                .input()
                .len(3)
                .unit("m")
                .start(0.0)
                .describe("In"),
        );
        b.add_real(
            T::real("y")
                .output()
                .len(3)
                .unit("N")
                .depends(Dependencies::None)
                .describe("Out"),
        );
        b.build().expect("table")
    }

    const GOOD: &str = "//! Model.\n//!\n//! | variable | causality | size | unit |\n\
        //! |---|---|---|---|\n//! | `u` | input | n | m |\n\
        //! | `y` | output (no direct dependency on inputs) | 3 | N |\n//!\n//! More.";

    #[test]
    fn a_table_that_matches_passes_and_every_drift_is_named() {
        let n = |s: &str| (s == "n").then_some(3);
        assert_eq!(check_signal_table(GOOD, &table(), n), Ok(()));
        for (from, to, says) in [
            ("| m |", "| mm |", "documented in \"mm\", declared in \"m\""),
            (
                "| input |",
                "| output |",
                "u: documented as output, declared input",
            ),
            (
                "| 3 | N |",
                "| 4 | N |",
                "documented size 4 = 4, declared 3",
            ),
            ("| n | m |", "| q | m |", "unknown size \"q\""),
            (
                "//! | `u` | input | n | m |\n",
                "",
                "are not the table's inputs and outputs",
            ),
        ] {
            let doc = GOOD.replace(from, to);
            let e = check_signal_table(&doc, &table(), n).expect_err(from);
            assert!(e.contains(says), "{from}: {e}");
        }
    }
}
