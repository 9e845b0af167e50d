#include "report/localization_tables.h"

#include <fmt/format.h>

#include <cmath>

namespace hscloc {
namespace {

std::string ThresholdTitle(const PoseThreshold& threshold) {
  return fmt::format("({:g} m, {:g}°)", threshold.position, threshold.rotation_deg);
}

std::string Percent(double fraction) { return fmt::format("{:.1f}%", 100 * fraction); }

std::string Error(double value, const char* unit) {
  return std::isfinite(value) ? fmt::format("{:.3g} {}", value, unit) : std::string("–");
}

std::string Milliseconds(double value) {
  return std::isfinite(value) ? fmt::format("{:.1f}", value) : std::string("–");
}

std::vector<PoseThreshold> ThresholdsOf(const std::vector<ConditionAccuracy>& accuracies) {
  return accuracies.empty() ? std::vector<PoseThreshold>() : accuracies.front().thresholds;
}

}  // namespace

HtmlTable AccuracyTable(const std::vector<ConditionAccuracy>& accuracies,
                        const std::string& caption) {
  HtmlTable table;
  table.caption = caption;
  table.header = {"condition", "queries", "estimated"};
  for (const PoseThreshold& threshold : ThresholdsOf(accuracies)) {
    table.header.push_back(ThresholdTitle(threshold));
  }
  table.header.insert(table.header.end(), {"median position", "median rotation"});
  for (const ConditionAccuracy& accuracy : accuracies) {
    std::vector<std::string> row = {accuracy.condition, std::to_string(accuracy.num_queries),
                                    std::to_string(accuracy.num_estimated)};
    for (const double fraction : accuracy.localized_fraction) row.push_back(Percent(fraction));
    row.push_back(Error(accuracy.median_position, "m"));
    row.push_back(Error(accuracy.median_rotation_deg, "°"));
    table.rows.push_back(std::move(row));
  }
  return table;
}

HtmlTable AblationTable(const AblationResults& results, const std::string& caption) {
  HtmlTable table;
  table.caption = caption;
  table.num_label_columns = 2;
  table.header = {"variant", "condition"};
  std::vector<ConditionAccuracy> accuracies;
  for (const AblationCell& cell : results.cells) accuracies.push_back(cell.accuracy);
  for (const PoseThreshold& threshold : ThresholdsOf(accuracies)) {
    table.header.push_back(ThresholdTitle(threshold));
  }
  table.header.insert(table.header.end(),
                      {"median position", "candidates posed", "matches kept", "total (ms, mean)"});
  for (const AblationCell& cell : results.cells) {
    std::vector<std::string> row = {cell.variant, cell.condition};
    for (const double fraction : cell.accuracy.localized_fraction) row.push_back(Percent(fraction));
    row.push_back(Error(cell.accuracy.median_position, "m"));
    row.push_back(
        fmt::format("{:.1f} of {:.1f}", cell.mean_candidates_evaluated, cell.mean_candidates));
    row.push_back(fmt::format("{:.0f}", cell.mean_matches));
    row.push_back(Milliseconds(cell.timings.Mean().total_ms));
    table.rows.push_back(std::move(row));
  }
  return table;
}

HtmlTable LatencyTable(const AblationResults& results, const std::string& variant,
                       const std::string& caption) {
  HtmlTable table;
  table.caption = caption;
  table.header = {"condition", "queries",    "retrieval", "match",    "visibility",
                  "pose",      "total mean", "total p50", "total p90"};
  for (const std::string& condition : results.conditions) {
    const StageTimingAccumulator& timings = results.At(variant, condition).timings;
    const StageTimings mean = timings.Mean();
    table.rows.push_back({condition, std::to_string(timings.count()),
                          Milliseconds(mean.retrieval_ms), Milliseconds(mean.match_ms),
                          fmt::format("{:.2f}", mean.visibility_ms), Milliseconds(mean.pose_ms),
                          Milliseconds(mean.total_ms), Milliseconds(timings.TotalPercentileMs(0.5)),
                          Milliseconds(timings.TotalPercentileMs(0.9))});
  }
  return table;
}

}  // namespace hscloc
