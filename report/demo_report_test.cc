#include "report/demo_report.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "report/html_test_support.h"
#include "util/testing.h"

namespace hscloc {
namespace {

using testing::CountOf;
using ::testing::HasSubstr;

DemoReport SmallReport() {
  DemoReport report;
  report.summary = "synthetic city 'small' & friends";
  const std::vector<QueryPoseError> errors = {{"a.jpg", true, 0.1, 1}, {"b.jpg", false}};
  report.accuracy = {SummarizeAccuracy("day", errors, AachenThresholds()),
                     SummarizeAccuracy("night", errors, AachenThresholds())};
  report.top_view.points_in_world = {{0, 0, 0}, {10, 5, 0}};
  report.top_view.queries = {{"a.jpg", {}, Rigid3d()}, {"b.jpg", {}, std::nullopt}};
  report.ablations.variants = {"paper", "top-1"};
  report.ablations.conditions = {"day", "night"};
  for (const std::string& variant : report.ablations.variants) {
    for (const std::string& condition : report.ablations.conditions) {
      AblationCell cell;
      cell.variant = variant;
      cell.condition = condition;
      cell.accuracy = SummarizeAccuracy(condition, errors, AachenThresholds());
      cell.timings.Add({1, 2, 3, 4, 10});
      report.ablations.cells.push_back(cell);
    }
  }
  report.latency_variant = "paper";
  report.match_pictures = {"<svg class='match'></svg>", "<svg class='match'></svg>"};
  return report;
}

TEST(DemoReportTest, TablesFiguresAndPicturesInOneBalancedPage) {
  const std::string html = RenderDemoReport(SmallReport());
  EXPECT_EQ(testing::UnbalancedTag(html), "");
  EXPECT_THAT(html, HasSubstr("<p>synthetic city &#39;small&#39; &amp; friends</p>"));
  // Accuracy (2 conditions), ablations (2 x 2), latency (2 conditions): header row + rows.
  EXPECT_EQ(CountOf(html, "<table>"), 3u);
  EXPECT_EQ(CountOf(html, "<tr>"), (1 + 2) + (1 + 4) + (1 + 2));
  // The error curves and the top view side by side, in the first row of figures.
  const size_t first_row = html.find("<div class='figures'>");
  const size_t second_row = html.find("<div class='figures'>", first_row + 1);
  ASSERT_NE(second_row, std::string::npos);
  const std::string figures = html.substr(first_row, second_row - first_row);
  EXPECT_EQ(CountOf(figures, "<figure>"), 2u);
  EXPECT_THAT(figures, HasSubstr("Cumulative pose errors"));
  EXPECT_THAT(figures, HasSubstr("class='query-truth'"));
  // No raw Markdown or text dumps.
  EXPECT_EQ(CountOf(html, "<pre>"), 0u);
  EXPECT_EQ(CountOf(html, "| ---"), 0u);
  EXPECT_EQ(CountOf(html.substr(second_row), "class='match'"), 2u);
}

TEST(DemoReportTest, NoPicturesNoSection) {
  DemoReport report = SmallReport();
  report.match_pictures.clear();
  const std::string html = RenderDemoReport(report);
  EXPECT_EQ(CountOf(html, "<div class='figures'>"), 1u);
  EXPECT_THAT(html, ::testing::Not(HasSubstr("Inlier matches")));
  report.latency_variant = "absent";
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { RenderDemoReport(report); }),
              HasSubstr("'absent'"));
}

}  // namespace
}  // namespace hscloc
