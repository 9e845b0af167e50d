#include "report/html.h"

#include <fmt/format.h>

#include "util/check.h"

namespace hscloc {
namespace {

constexpr const char* kStyle =
    "body{font-family:sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222}"
    "table{border-collapse:collapse;margin:0.5em 0 1.5em}"
    "caption{text-align:left;font-weight:bold;padding:0.3em 0}"
    "th,td{border:1px solid #ccc;padding:0.25em 0.6em}"
    "th{background:#eee}td.number{text-align:right;font-variant-numeric:tabular-nums}"
    "tbody tr:nth-child(even){background:#f8f8f8}"
    ".figures{display:flex;flex-wrap:wrap;gap:1.5em;align-items:flex-start}"
    "figure{margin:0}figcaption{font-size:0.9em;color:#555;max-width:560px}";

}  // namespace

std::string EscapeHtml(std::string_view text) {
  std::string escaped;
  escaped.reserve(text.size());
  for (const char c : text) {
    switch (c) {
      case '&':
        escaped += "&amp;";
        break;
      case '<':
        escaped += "&lt;";
        break;
      case '>':
        escaped += "&gt;";
        break;
      case '"':
        escaped += "&quot;";
        break;
      case '\'':
        escaped += "&#39;";
        break;
      default:
        escaped += c;
    }
  }
  return escaped;
}

std::string RenderHtmlTable(const HtmlTable& table) {
  std::string html = "<table>\n";
  if (!table.caption.empty())
    html += fmt::format("<caption>{}</caption>\n", EscapeHtml(table.caption));
  html += "<thead><tr>";
  for (const std::string& title : table.header)
    html += fmt::format("<th>{}</th>", EscapeHtml(title));
  html += "</tr></thead>\n<tbody>\n";
  for (size_t r = 0; r < table.rows.size(); ++r) {
    const std::vector<std::string>& row = table.rows[r];
    if (row.size() != table.header.size()) {
      ThrowInvalidArgument("table '{}': row {} has {} cells, the header {}", table.caption, r,
                           row.size(), table.header.size());
    }
    html += "<tr>";
    for (size_t c = 0; c < row.size(); ++c) {
      const bool label = static_cast<int>(c) < table.num_label_columns;
      html += fmt::format(label ? "<td>{}</td>" : "<td class='number'>{}</td>", EscapeHtml(row[c]));
    }
    html += "</tr>\n";
  }
  html += "</tbody>\n</table>\n";
  return html;
}

HtmlPage::HtmlPage(std::string title) : title_(std::move(title)) {}

void HtmlPage::AddHeading(std::string_view text) {
  body_ += fmt::format("<h2>{}</h2>\n", EscapeHtml(text));
}

void HtmlPage::AddParagraph(std::string_view text) {
  body_ += fmt::format("<p>{}</p>\n", EscapeHtml(text));
}

void HtmlPage::AddTable(const HtmlTable& table) { body_ += RenderHtmlTable(table); }

void HtmlPage::AddFigureRow(const std::vector<HtmlFigure>& figures) {
  body_ += "<div class='figures'>\n";
  for (const HtmlFigure& figure : figures) {
    body_ += "<figure>\n" + figure.svg;
    if (!figure.caption.empty()) {
      body_ += fmt::format("<figcaption>{}</figcaption>\n", EscapeHtml(figure.caption));
    }
    body_ += "</figure>\n";
  }
  body_ += "</div>\n";
}

std::string HtmlPage::Render() const {
  return fmt::format(
      "<!doctype html>\n<html lang='en'>\n<head>\n<meta charset='utf-8'>\n<title>{0}</title>\n"
      "<style>{1}</style>\n</head>\n<body>\n<h1>{0}</h1>\n{2}</body>\n</html>\n",
      EscapeHtml(title_), kStyle, body_);
}

}  // namespace hscloc
