//! A self-contained HTML page: inline CSS, figures inline as SVG, no scripts or external links.

use super::plot::{Figure, escape};

/// An HTML page under construction.
#[derive(Debug, Clone)]
pub struct Page {
    title: String,
    body: String,
}

const STYLE: &str = "body{font-family:sans-serif;max-width:1240px;margin:1em auto;padding:0 1em;color:#222}\
svg{max-width:100%;height:auto}\
h1{font-size:1.6em}h2{font-size:1.3em;border-bottom:1px solid #ccc;margin-top:2em}h3{font-size:1.1em}\
figure{margin:1em 0}figcaption{font-size:.9em;color:#444;max-width:1100px}\
table{border-collapse:collapse;font-size:.85em;margin:.5em 0}\
td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}th{background:#f4f4f4}\
td:first-child{text-align:left}tr.weak td{background:#fff3e0}\
pre{background:#f7f7f7;padding:.5em;font-size:.8em;overflow-x:auto}.note{color:#8a4b00}";

impl Page {
    pub fn new(title: &str) -> Self {
        Self { title: title.to_string(), body: String::new() }
    }

    pub fn heading(&mut self, level: u8, text: &str) {
        let l = level.clamp(1, 4);
        self.body.push_str(&format!("<h{l}>{}</h{l}>\n", escape(text)));
    }

    /// A paragraph of plain text (escaped).
    pub fn text(&mut self, text: &str) {
        self.body.push_str(&format!("<p>{}</p>\n", escape(text)));
    }

    /// A highlighted remark (escaped).
    pub fn note(&mut self, text: &str) {
        self.body.push_str(&format!("<p class=\"note\">{}</p>\n", escape(text)));
    }

    pub fn pre(&mut self, text: &str) {
        self.body.push_str(&format!("<pre>{}</pre>\n", escape(text)));
    }

    /// A figure inline, its caption, and the name of its separate SVG file if there is one.
    pub fn figure(&mut self, fig: &Figure, file: Option<&str>) {
        self.body.push_str(&format!(
            "<figure id=\"{}\">\n{}\n<figcaption><b>{}</b> {}{}</figcaption>\n</figure>\n",
            escape(&fig.name),
            fig.svg.trim(),
            escape(&fig.title),
            escape(&fig.caption),
            file.map(|f| format!(" (also <code>{}</code>)", escape(f))).unwrap_or_default()
        ));
    }

    /// A table of text cells (escaped); rows with `marked` set are highlighted.
    pub fn table(&mut self, header: &[&str], rows: &[(Vec<String>, bool)]) {
        self.body.push_str("<table>\n<tr>");
        for h in header {
            self.body.push_str(&format!("<th>{}</th>", escape(h)));
        }
        self.body.push_str("</tr>\n");
        for (cells, marked) in rows {
            self.body.push_str(if *marked { "<tr class=\"weak\">" } else { "<tr>" });
            for c in cells {
                self.body.push_str(&format!("<td>{}</td>", escape(c)));
            }
            self.body.push_str("</tr>\n");
        }
        self.body.push_str("</table>\n");
    }

    pub fn finish(self) -> String {
        format!(
            "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>{}</title>\n<style>{STYLE}</style>\n</head>\n<body>\n<h1>{}</h1>\n{}</body>\n</html>\n",
            escape(&self.title),
            escape(&self.title),
            self.body
        )
    }
}
