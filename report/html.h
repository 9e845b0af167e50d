// Building an HTML page from parts: headings, paragraphs, tables made from rows of text, and rows
// of figures (inline SVG) side by side. Every piece of text is escaped; SVG markup is trusted (it
// comes from this folder's figure writers).
#pragma once

#include <string>
#include <string_view>
#include <vector>

namespace hscloc {

// `text` with &, <, >, " and ' replaced by their character references: safe inside elements and
// inside quoted attribute values, of HTML and of SVG.
std::string EscapeHtml(std::string_view text);

// A table of plain-text cells. Cells of the first `num_label_columns` columns are left-aligned,
// the others (numbers) right-aligned.
struct HtmlTable {
  std::string caption;  // above the table; none when empty
  std::vector<std::string> header;
  std::vector<std::vector<std::string>> rows;  // each as many cells as the header
  int num_label_columns = 1;
};

// `<table>` with a `<thead>` row of `<th>` and a `<tbody>` row of `<td>` per row. Throws
// std::invalid_argument naming the row whose cell count differs from the header's.
std::string RenderHtmlTable(const HtmlTable& table);

// One figure of a row: an SVG document and the caption under it.
struct HtmlFigure {
  std::string svg;
  std::string caption;
};

// A self-contained page (inline style, inline figures), built in order.
class HtmlPage {
 public:
  explicit HtmlPage(std::string title);

  // A section heading (`<h2>`).
  void AddHeading(std::string_view text);
  void AddParagraph(std::string_view text);
  void AddTable(const HtmlTable& table);
  // Figures next to each other, wrapping onto the next line where the window is narrow.
  void AddFigureRow(const std::vector<HtmlFigure>& figures);

  // The whole document, `<!doctype html>` to `</html>`, the title as `<title>` and `<h1>`.
  std::string Render() const;

 private:
  std::string title_;
  std::string body_;
};

}  // namespace hscloc
