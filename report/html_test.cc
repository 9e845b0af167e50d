#include "report/html.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "report/html_test_support.h"
#include "util/testing.h"

namespace hscloc {
namespace {

using testing::CountOf;
using ::testing::HasSubstr;
using ::testing::Not;
using testing::UnbalancedTag;

TEST(HtmlTest, EscapesMarkupAndQuotes) {
  EXPECT_EQ(EscapeHtml("a<b>&\"c'"), "a&lt;b&gt;&amp;&quot;c&#39;");
  EXPECT_EQ(EscapeHtml("plain text, 0.25 m"), "plain text, 0.25 m");
  EXPECT_EQ(EscapeHtml(""), "");
}

TEST(HtmlTest, TableHasARowOfCellsPerInputRowAndEscapesThem) {
  HtmlTable table;
  table.caption = "caption & more";
  table.header = {"name", "a", "b"};
  table.rows = {{"<script>", "1", "2"}, {"x", "3", "4"}, {"y", "5", "6"}, {"z", "7", "8"}};
  const std::string html = RenderHtmlTable(table);
  EXPECT_EQ(UnbalancedTag(html), "");
  EXPECT_EQ(CountOf(html, "<table>"), 1u);
  EXPECT_EQ(CountOf(html, "<th>"), 3u);
  EXPECT_EQ(CountOf(html, "<tr>"), 1 + table.rows.size());
  EXPECT_EQ(CountOf(html, "<td"), 3 * table.rows.size());
  // The first column is a label, the others are numbers (right-aligned).
  EXPECT_EQ(CountOf(html, "<td class='number'>"), 2 * table.rows.size());
  EXPECT_THAT(html, HasSubstr("<td>&lt;script&gt;</td>"));
  EXPECT_THAT(html, Not(HasSubstr("<script>")));
  EXPECT_THAT(html, HasSubstr("<caption>caption &amp; more</caption>"));
  // Rows keep their order.
  EXPECT_LT(html.find(">x<"), html.find(">y<"));
  EXPECT_LT(html.find(">y<"), html.find(">z<"));
}

TEST(HtmlTest, ARowOfTheWrongWidthIsRejected) {
  HtmlTable table;
  table.caption = "accuracy";
  table.header = {"a", "b"};
  table.rows = {{"1", "2"}, {"3"}};
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { RenderHtmlTable(table); }),
              HasSubstr("row 1 has 1 cells, the header 2"));
}

TEST(HtmlTest, PageHoldsItsPartsInOrderAndIsBalanced) {
  HtmlPage page("demo <1>");
  page.AddParagraph("a & b");
  page.AddHeading("Tables");
  page.AddTable({"", {"h"}, {{"v"}}, 1});
  page.AddFigureRow({{"<svg><circle r='1'/></svg>", "left"}, {"<svg></svg>", "right <2>"}});
  const std::string html = page.Render();
  EXPECT_THAT(html, ::testing::StartsWith("<!doctype html>"));
  EXPECT_EQ(UnbalancedTag(html), "");
  EXPECT_THAT(html, HasSubstr("<title>demo &lt;1&gt;</title>"));
  EXPECT_THAT(html, HasSubstr("<h1>demo &lt;1&gt;</h1>"));
  EXPECT_THAT(html, HasSubstr("<p>a &amp; b</p>"));
  EXPECT_EQ(CountOf(html, "<figure>"), 2u);
  EXPECT_THAT(html, HasSubstr("<figcaption>right &lt;2&gt;</figcaption>"));
  // Both figures in one row, after the table.
  EXPECT_EQ(CountOf(html, "<div class='figures'>"), 1u);
  EXPECT_LT(html.find("</table>"), html.find("<div class='figures'>"));
  EXPECT_LT(html.find("<h2>Tables</h2>"), html.find("<table>"));
}

TEST(HtmlTestSupportTest, FindsUnbalancedMarkup) {
  EXPECT_EQ(UnbalancedTag("<p><b>x</b></p>"), "");
  EXPECT_NE(UnbalancedTag("<p><b>x</p></b>"), "");
  EXPECT_NE(UnbalancedTag("<table><tr>"), "");
}

}  // namespace
}  // namespace hscloc
