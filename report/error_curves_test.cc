#include "report/error_curves.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "report/html_test_support.h"

namespace hscloc {
namespace {

using testing::CountOf;
using ::testing::HasSubstr;

QueryPoseError Error(const std::string& name, double position, double rotation_deg) {
  return {name, true, position, rotation_deg};
}

TEST(ErrorCurvesTest, ACurvePerConditionAndPanel) {
  const std::vector<ConditionAccuracy> accuracies = {
      SummarizeAccuracy("day", {Error("a", 0.1, 1), Error("b", 0.3, 3)}, AachenThresholds()),
      SummarizeAccuracy("night",
                        {Error("c", 0.2, 0.5), {"d", false}, Error("e", 2, 8), Error("f", 40, 90)},
                        AachenThresholds())};
  const std::string svg = CumulativeErrorSvg(accuracies, "test");
  EXPECT_THAT(svg, ::testing::StartsWith("<svg"));
  EXPECT_EQ(testing::UnbalancedTag(svg), "");
  EXPECT_THAT(svg, HasSubstr("day (2 queries)"));
  EXPECT_THAT(svg, HasSubstr("night (4 queries)"));
  EXPECT_EQ(CountOf(svg, "<polyline"), 4u);  // two conditions x (position, rotation)
  // Three dashed threshold lines per panel.
  EXPECT_EQ(CountOf(svg, "stroke-dasharray"), 6u);
}

TEST(ErrorCurvesTest, TitleAndConditionsAreEscaped) {
  const std::string svg = CumulativeErrorSvg(
      {SummarizeAccuracy("<day>", {Error("a", 0.1, 1)}, AachenThresholds())}, "a & b");
  EXPECT_THAT(svg, HasSubstr(">a &amp; b<"));
  EXPECT_THAT(svg, HasSubstr("&lt;day&gt; (1 queries)"));
}

}  // namespace
}  // namespace hscloc
