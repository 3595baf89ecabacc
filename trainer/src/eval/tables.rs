//! Markdown tables shaped like the paper's Tables 1–3 (Sec. 4.3 and 4.5).
//!
//! * Table 1 (material accuracy): rows such as "standalone" / "combined"; columns material L2
//!   in the normalised parameters the network is trained on (the raw-scale figure, dominated by
//!   γ up to 1e4, stays in the JSON) and the L2 and SSIM of I' rendered with the predicted
//!   material;
//! * Table 2 (normal accuracy, car category): columns normals cosine and I' L2, SSIM;
//! * Table 3 (material transfer): methods as **columns**, rows L2 and SSIM of O'.
//!
//! The paper's two-level headers ("material / L2", "rendering / L2") become one header line.
//! Decimals follow the paper: 4 for material L2, cosine and SSIM; image L2 with 1 decimal in
//! Tables 1 and 3 and 4 in Table 2. A metric that was not scored prints as "–".

use super::{I_PRIME, Metrics, O_PRIME};

/// One row (Tables 1, 2) or column (Table 3): a method or configuration and its metrics.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TableRow {
    /// Shown as the row (column) label, e.g. "standalone", "combined", "mean material".
    pub name: String,
    /// The metrics of that method over the evaluated split.
    pub metrics: Metrics,
}

fn cell(v: Option<f64>, decimals: usize) -> String {
    v.map_or_else(|| "–".to_owned(), |v| format!("{v:.decimals$}"))
}

/// Labels come from callers; a '|' would split the cell.
fn label(name: &str) -> String {
    name.replace('|', "\\|")
}

fn render(header: &[String], rows: &[Vec<String>]) -> String {
    let line = |cells: &[String]| format!("| {} |\n", cells.join(" | "));
    let mut out = line(header);
    let align: Vec<String> = (0..header.len())
        .map(|i| if i == 0 { ":--" } else { "--:" }.to_owned())
        .collect();
    out += &line(&align);
    for r in rows {
        out += &line(r);
    }
    out
}

fn by_rows(header: &[&str], rows: &[TableRow], cells: impl Fn(&Metrics) -> Vec<String>) -> String {
    let header: Vec<String> = header.iter().map(|h| (*h).to_owned()).collect();
    let body: Vec<Vec<String>> = rows
        .iter()
        .map(|r| std::iter::once(label(&r.name)).chain(cells(&r.metrics)).collect())
        .collect();
    render(&header, &body)
}

/// The material column's header: the scale is named, since the raw one differs by orders of
/// magnitude.
const MATERIAL_L2: &str = "material L2 (normalised)";

/// Table 1: material L2 (normalised scale, see [`super::material_l2_normalised`]), I' L2,
/// I' SSIM.
pub fn table1_markdown(rows: &[TableRow]) -> String {
    by_rows(&["", MATERIAL_L2, "rendering L2", "rendering SSIM"], rows, |m| {
        vec![
            cell(m.material_l2_normalised.value(), 4),
            cell(m.image_l2(I_PRIME), 1),
            cell(m.image_ssim(I_PRIME), 4),
        ]
    })
}

/// Table 2: normals cosine, I' L2, I' SSIM.
pub fn table2_markdown(rows: &[TableRow]) -> String {
    by_rows(&["", "normals cosine", "rendering L2", "rendering SSIM"], rows, |m| {
        vec![
            cell(m.normal_cosine.value(), 4),
            cell(m.image_l2(I_PRIME), 4),
            cell(m.image_ssim(I_PRIME), 4),
        ]
    })
}

/// The full pipeline (n', m', L' all predicted): I' and O' L2 and SSIM, normals cosine,
/// material L2 (normalised scale).
pub fn pipeline_markdown(rows: &[TableRow]) -> String {
    by_rows(
        &[
            "",
            "I' L2",
            "I' SSIM",
            "O' L2",
            "O' SSIM",
            "normals cosine",
            MATERIAL_L2,
        ],
        rows,
        |m| {
            vec![
                cell(m.image_l2(I_PRIME), 1),
                cell(m.image_ssim(I_PRIME), 4),
                cell(m.image_l2(O_PRIME), 1),
                cell(m.image_ssim(O_PRIME), 4),
                cell(m.normal_cosine.value(), 4),
                cell(m.material_l2_normalised.value(), 4),
            ]
        },
    )
}

/// Table 3: one column per method, rows L2 and SSIM of the edited image O'.
pub fn table3_markdown(methods: &[TableRow]) -> String {
    let header: Vec<String> = std::iter::once(String::new())
        .chain(methods.iter().map(|m| label(&m.name)))
        .collect();
    let row = |name: &str, f: &dyn Fn(&Metrics) -> String| {
        std::iter::once(name.to_owned())
            .chain(methods.iter().map(|m| f(&m.metrics)))
            .collect::<Vec<_>>()
    };
    let body = [
        row("L2", &|m| cell(m.image_l2(O_PRIME), 1)),
        row("SSIM", &|m| cell(m.image_ssim(O_PRIME), 4)),
    ];
    render(&header, &body)
}

#[cfg(test)]
mod tests {
    use super::super::{ImageMetrics, Mean};
    use super::*;

    fn mean(v: f64) -> Mean {
        Mean { sum: 2.0 * v, count: 2 }
    }

    fn rows() -> Vec<TableRow> {
        let mut standalone = Metrics {
            material_l2: mean(1.35e9),
            material_l2_normalised: mean(4.1038),
            ..Default::default()
        };
        standalone.images.insert(
            I_PRIME.into(),
            ImageMetrics {
                l2: mean(544.1),
                ssim: mean(0.9297),
            },
        );
        let mut combined = Metrics {
            normal_cosine: mean(0.905),
            ..Default::default()
        };
        combined.images.insert(
            O_PRIME.into(),
            ImageMetrics {
                l2: mean(530.94),
                ssim: mean(0.95571),
            },
        );
        vec![
            TableRow {
                name: "standalone".into(),
                metrics: standalone,
            },
            TableRow {
                name: "a|b".into(),
                metrics: combined,
            },
        ]
    }

    #[test]
    fn table1_has_the_paper_columns_and_dashes_for_missing_entries() {
        assert_eq!(
            table1_markdown(&rows()),
            "|  | material L2 (normalised) | rendering L2 | rendering SSIM |\n\
             | :-- | --: | --: | --: |\n\
             | standalone | 4.1038 | 544.1 | 0.9297 |\n\
             | a\\|b | – | – | – |\n"
        );
    }

    #[test]
    fn table2_shows_cosine_and_four_decimal_l2() {
        assert_eq!(
            table2_markdown(&rows()),
            "|  | normals cosine | rendering L2 | rendering SSIM |\n\
             | :-- | --: | --: | --: |\n\
             | standalone | – | 544.1000 | 0.9297 |\n\
             | a\\|b | 0.9050 | – | – |\n"
        );
    }

    #[test]
    fn table3_has_methods_as_columns() {
        assert_eq!(
            table3_markdown(&rows()),
            "|  | standalone | a\\|b |\n\
             | :-- | --: | --: |\n\
             | L2 | – | 530.9 |\n\
             | SSIM | – | 0.9557 |\n"
        );
        assert_eq!(
            table1_markdown(&[]),
            "|  | material L2 (normalised) | rendering L2 | rendering SSIM |\n| :-- | --: | --: | --: |\n"
        );
    }
}
