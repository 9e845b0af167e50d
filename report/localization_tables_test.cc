#include "report/localization_tables.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "report/html_test_support.h"
#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;

QueryPoseError Error(const std::string& name, double position, double rotation_deg) {
  return {name, true, position, rotation_deg};
}

// Every row as wide as the header.
void ExpectRectangular(const HtmlTable& table) {
  for (const std::vector<std::string>& row : table.rows) {
    EXPECT_EQ(row.size(), table.header.size());
  }
}

AblationResults TwoByTwo() {
  AblationResults results;
  results.variants = {"paper", "top-1"};
  results.conditions = {"day", "night"};
  for (const std::string& variant : results.variants) {
    for (const std::string& condition : results.conditions) {
      AblationCell cell;
      cell.variant = variant;
      cell.condition = condition;
      cell.accuracy = SummarizeAccuracy(
          condition, {Error("a", 0.1, 1), Error("b", 1, 3), {"c", false}}, AachenThresholds());
      cell.timings.Add({1, 20, 0.5, 4, 30});
      cell.timings.Add({3, 40, 0.5, 6, 50});
      cell.mean_candidates = 10;
      cell.mean_candidates_evaluated = variant == "paper" ? 10 : 1;
      cell.mean_matches = 123.4;
      results.cells.push_back(cell);
    }
  }
  return results;
}

TEST(LocalizationTablesTest, AccuracyHasARowPerConditionAndAColumnPerThreshold) {
  const std::vector<ConditionAccuracy> accuracies = {
      SummarizeAccuracy("day", {Error("a", 0.1, 1), Error("b", 0.3, 1)}, AachenThresholds()),
      SummarizeAccuracy("night", {Error("c", 0.1, 1), {"d", false}}, AachenThresholds())};
  const HtmlTable table = AccuracyTable(accuracies, "accuracy");
  ExpectRectangular(table);
  ASSERT_EQ(table.rows.size(), 2u);
  EXPECT_EQ(table.header.size(), 3 + 3 + 2u);
  EXPECT_EQ(table.header[3], "(0.25 m, 2°)");
  EXPECT_EQ(table.header[5], "(5 m, 10°)");
  EXPECT_THAT(table.rows[0],
              ElementsAre("day", "2", "2", "50.0%", "100.0%", "100.0%", "0.2 m", "1 °"));
  // A missing estimate: one of two estimated, and the median of (0.1, inf) is infinite.
  EXPECT_EQ(table.rows[1][2], "1");
  EXPECT_EQ(table.rows[1][3], "50.0%");
  EXPECT_EQ(table.rows[1][6], "–");
}

TEST(LocalizationTablesTest, AblationsHaveARowPerVariantAndCondition) {
  const HtmlTable table = AblationTable(TwoByTwo(), "ablations");
  ExpectRectangular(table);
  EXPECT_EQ(table.num_label_columns, 2);
  ASSERT_EQ(table.rows.size(), 4u);
  EXPECT_THAT(table.rows[0], ElementsAre("paper", "day", "33.3%", "33.3%", "66.7%", "1 m",
                                         "10.0 of 10.0", "123", "40.0"));
  EXPECT_EQ(table.rows[3][0], "top-1");
  EXPECT_EQ(table.rows[3][1], "night");
  EXPECT_EQ(table.rows[3][6], "1.0 of 10.0");
  const std::string html = RenderHtmlTable(table);
  EXPECT_EQ(testing::UnbalancedTag(html), "");
  EXPECT_EQ(testing::CountOf(html, "<tr>"), 5u);
}

TEST(LocalizationTablesTest, LatencyHasARowPerConditionOfTheVariant) {
  const HtmlTable table = LatencyTable(TwoByTwo(), "paper", "latency");
  ExpectRectangular(table);
  ASSERT_EQ(table.rows.size(), 2u);
  EXPECT_THAT(table.rows[1],
              ElementsAre("night", "2", "2.0", "30.0", "0.50", "5.0", "40.0", "40.0", "48.0"));
  EXPECT_THAT(testing::InvalidArgumentMessage([] { LatencyTable(TwoByTwo(), "nn", ""); }),
              HasSubstr("'nn'"));
}

}  // namespace
}  // namespace hscloc
