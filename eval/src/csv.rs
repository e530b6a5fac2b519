//! A small CSV writer (fields here never contain commas or quotes; any that do are quoted).

use std::io::Write;
use std::path::Path;

/// A CSV table: a header and rows of fields.
#[derive(Clone, Debug, Default)]
pub struct Table {
    /// Column names.
    pub header: Vec<String>,
    /// Rows, each as long as the header.
    pub rows: Vec<Vec<String>>,
}

fn field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// A number with `digits` decimals; an empty field for `None` or a non-finite value.
pub fn num(v: Option<f64>, digits: usize) -> String {
    match v {
        Some(x) if x.is_finite() => format!("{x:.digits$}"),
        _ => String::new(),
    }
}

impl Table {
    /// A table with these column names.
    pub fn new(header: &[&str]) -> Table {
        Table { header: header.iter().map(|s| s.to_string()).collect(), rows: Vec::new() }
    }

    /// Appends a row.
    pub fn push(&mut self, row: Vec<String>) {
        debug_assert_eq!(row.len(), self.header.len());
        self.rows.push(row);
    }

    /// The CSV text.
    pub fn to_csv(&self) -> String {
        let mut s = self.header.iter().map(|h| field(h)).collect::<Vec<_>>().join(",");
        s.push('\n');
        for r in &self.rows {
            s.push_str(&r.iter().map(|f| field(f)).collect::<Vec<_>>().join(","));
            s.push('\n');
        }
        s
    }

    /// Writes the CSV file.
    pub fn write(&self, path: &Path) -> std::io::Result<()> {
        let mut f = std::fs::File::create(path)?;
        f.write_all(self.to_csv().as_bytes())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_and_numbers() {
        let mut t = Table::new(&["a", "b"]);
        t.push(vec!["x,y".into(), num(Some(1.23456), 2)]);
        t.push(vec!["z".into(), num(Some(f64::NAN), 2)]);
        assert_eq!(t.to_csv(), "a,b\n\"x,y\",1.23\nz,\n");
    }
}
