//! Aligned plain-text tables for human-readable output.

/// How a column's cells are padded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Align {
    /// Text: padded on the right.
    Left,
    /// Numbers: padded on the left.
    Right,
}

/// A table of text cells with a header row, rendered with columns two spaces apart.
#[derive(Debug)]
pub struct Table {
    /// Column headings; an empty heading row is not printed.
    header: Vec<String>,
    /// Alignment per column.
    align: Vec<Align>,
    /// The rows, each with at most as many cells as there are columns.
    rows: Vec<Vec<String>>,
}

impl Table {
    /// A table with the given columns `(heading, alignment)`.
    pub fn new(columns: &[(&str, Align)]) -> Self {
        Self {
            header: columns.iter().map(|(h, _)| (*h).to_owned()).collect(),
            align: columns.iter().map(|(_, a)| *a).collect(),
            rows: Vec::new(),
        }
    }

    /// Appends a row.
    pub fn row(&mut self, cells: Vec<String>) {
        self.rows.push(cells);
    }

    /// Renders the table, every line prefixed by `indent` and without trailing spaces.
    pub fn render(&self, indent: &str) -> String {
        let show_header = self.header.iter().any(|h| !h.is_empty());
        let mut widths = vec![0; self.align.len()];
        for row in std::iter::once(&self.header).filter(|_| show_header).chain(&self.rows) {
            for (width, cell) in widths.iter_mut().zip(row) {
                *width = (*width).max(cell.chars().count());
            }
        }
        let mut out = String::new();
        for row in std::iter::once(&self.header).filter(|_| show_header).chain(&self.rows) {
            let mut line = String::from(indent);
            for (i, cell) in row.iter().enumerate().take(widths.len()) {
                if i > 0 {
                    line.push_str("  ");
                }
                let pad = " ".repeat(widths[i].saturating_sub(cell.chars().count()));
                match self.align[i] {
                    Align::Left => {
                        line.push_str(cell);
                        line.push_str(&pad);
                    }
                    Align::Right => {
                        line.push_str(&pad);
                        line.push_str(cell);
                    }
                }
            }
            out.push_str(line.trim_end());
            out.push('\n');
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn columns_align_and_lines_have_no_trailing_spaces() {
        let mut t = Table::new(&[("name", Align::Left), ("n", Align::Right), ("x", Align::Left)]);
        t.row(vec!["a".into(), "10".into(), String::new()]);
        t.row(vec!["long".into(), "2".into(), "z".into()]);
        assert_eq!(t.render("  "), "  name   n  x\n  a     10\n  long   2  z\n");
    }
}
