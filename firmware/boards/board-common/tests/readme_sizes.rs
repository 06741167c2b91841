//! The boards README and BENCHMARKS.md quote the sizes `sizes.txt` records (which
//! `stm32-sizes.sh` measures and `BLESS=1` rewrites), so the documents cannot drift from
//! the measurement unnoticed.

const SIZES: &str = include_str!("../../sizes.txt");
const README: &str = include_str!("../../README.md");
const BENCHMARKS: &str = include_str!("../../../../BENCHMARKS.md");

/// `sizes.txt`'s rows: name, flash, ram, text, data, bss, stack, run.
fn recorded() -> Vec<(String, Vec<u64>)> {
    SIZES
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let mut f = l.split_whitespace();
            let name = f.next().expect("a name").to_owned();
            let v = f.map(|x| x.parse().expect("a number")).collect();
            (name, v)
        })
        .collect()
}

/// The numbers of a table row's cells: "88 368 (90 % of 96 KiB)" is 88368, "13 496 /
/// 4 144 B" is 13496 and 4144; cells without a leading number are skipped.
fn row_numbers(doc: &str, name: &str) -> Option<Vec<u64>> {
    let row = doc
        .lines()
        .find(|l| l.starts_with(&format!("| {name} |")))?;
    let mut out = Vec::new();
    for cell in row.split('|').skip(2) {
        let cell = cell.split('(').next().unwrap_or("");
        for part in cell.split('/') {
            let digits: String = part
                .trim()
                .trim_end_matches('B')
                .chars()
                .filter(|c| *c != ' ')
                .collect();
            if let Ok(n) = digits.parse() {
                out.push(n);
            }
        }
    }
    Some(out)
}

#[test]
fn the_readme_and_benchmarks_quote_sizes_txt() {
    let rows = recorded();
    assert!(rows.len() >= 2, "{rows:?}");
    for (name, v) in rows {
        let [flash, ram, _text, data, bss, stack, run] = v[..] else {
            panic!("{name}: {v:?}");
        };
        assert_eq!(
            row_numbers(README, &name),
            Some(vec![flash, ram, stack, run]),
            "README.md's size table row for {name} must quote sizes.txt \
             (flash, RAM, stack bound boot / running)"
        );
        assert_eq!(
            row_numbers(BENCHMARKS, &name),
            Some(vec![flash, ram, data + bss, stack, run]),
            "BENCHMARKS.md's firmware size row for {name} must quote sizes.txt \
             (flash, RAM, statics, stack bound boot / running)"
        );
    }
}
