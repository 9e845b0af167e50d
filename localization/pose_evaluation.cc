#include "localization/pose_evaluation.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <unordered_map>

#include "util/check.h"

namespace hscloc {
namespace {

double Median(std::vector<double> values) {
  if (values.empty()) return std::numeric_limits<double>::infinity();
  const size_t middle = values.size() / 2;
  std::nth_element(values.begin(), values.begin() + middle, values.end());
  if (values.size() % 2 == 1) return values[middle];
  const double upper = values[middle];
  const double lower = *std::max_element(values.begin(), values.begin() + middle);
  return std::isinf(upper) ? upper : (lower + upper) / 2;
}

std::string FormatThreshold(const PoseThreshold& threshold) {
  return fmt::format("({:g} m, {:g} deg)", threshold.position, threshold.rotation_deg);
}

std::string FormatError(double value, const char* unit) {
  return std::isinf(value) ? std::string("-") : fmt::format("{:.3g} {}", value, unit);
}

}  // namespace

std::vector<PoseThreshold> AachenThresholds() { return {{0.25, 2}, {0.5, 5}, {5, 10}}; }

std::vector<QueryPoseError> ComputePoseErrors(const std::vector<NamedPose>& ground_truth,
                                              const std::vector<NamedPose>& results) {
  std::unordered_map<std::string, size_t> query_of_basename;
  for (size_t i = 0; i < ground_truth.size(); ++i) {
    const std::string basename = ImageBasename(ground_truth[i].name);
    if (!query_of_basename.emplace(basename, i).second) {
      ThrowInvalidArgument("ground truth: two queries share the basename '{}'", basename);
    }
  }
  std::vector<QueryPoseError> errors(ground_truth.size());
  for (size_t i = 0; i < ground_truth.size(); ++i) errors[i].name = ground_truth[i].name;
  for (const NamedPose& result : results) {
    const auto query = query_of_basename.find(ImageBasename(result.name));
    if (query == query_of_basename.end()) {
      ThrowInvalidArgument("results: '{}' is not a query of the ground truth", result.name);
    }
    QueryPoseError& error = errors[query->second];
    if (error.estimated) {
      ThrowInvalidArgument("results: two poses for the query '{}'", ImageBasename(result.name));
    }
    const Rigid3d& truth = ground_truth[query->second].cam_from_world;
    error.estimated = true;
    error.position = PositionError(result.cam_from_world, truth);
    error.rotation_deg = RotationErrorDeg(result.cam_from_world, truth);
  }
  return errors;
}

ConditionAccuracy SummarizeAccuracy(const std::string& condition,
                                    std::vector<QueryPoseError> errors,
                                    const std::vector<PoseThreshold>& thresholds) {
  ConditionAccuracy accuracy;
  accuracy.condition = condition;
  accuracy.num_queries = errors.size();
  accuracy.thresholds = thresholds;
  std::vector<double> positions;
  std::vector<double> rotations;
  for (const QueryPoseError& error : errors) {
    accuracy.num_estimated += error.estimated;
    positions.push_back(error.position);
    rotations.push_back(error.rotation_deg);
  }
  for (const PoseThreshold& threshold : thresholds) {
    const size_t within = std::count_if(errors.begin(), errors.end(), [&](const auto& error) {
      return error.position <= threshold.position && error.rotation_deg <= threshold.rotation_deg;
    });
    accuracy.localized_fraction.push_back(
        errors.empty() ? 0.0 : static_cast<double>(within) / static_cast<double>(errors.size()));
  }
  accuracy.median_position = Median(positions);
  accuracy.median_rotation_deg = Median(rotations);
  accuracy.errors = std::move(errors);
  return accuracy;
}

std::string FormatAccuracyTable(const std::vector<ConditionAccuracy>& accuracies) {
  if (accuracies.empty()) return "";
  std::string table = fmt::format("{:<10} {:>8}", "condition", "queries");
  for (const PoseThreshold& threshold : accuracies.front().thresholds) {
    table += fmt::format(" {:>16}", FormatThreshold(threshold));
  }
  table += fmt::format(" {:>16} {:>16}\n", "median position", "median rotation");
  for (const ConditionAccuracy& accuracy : accuracies) {
    table += fmt::format("{:<10} {:>8}", accuracy.condition, accuracy.num_queries);
    for (const double fraction : accuracy.localized_fraction) {
      table += fmt::format(" {:>15.1f}%", 100 * fraction);
    }
    table += fmt::format(" {:>16} {:>16}\n", FormatError(accuracy.median_position, "m"),
                         FormatError(accuracy.median_rotation_deg, "deg"));
  }
  return table;
}

ConditionQueries ConditionFromQueryList(const std::string& name,
                                        const std::filesystem::path& list) {
  ConditionQueries condition{name, {}};
  for (const QueryWithIntrinsics& query : ReadQueryList(list)) {
    condition.basenames.insert(ImageBasename(query.name));
  }
  return condition;
}

std::vector<ConditionQueries> ParseConditions(const std::string& text) {
  std::vector<ConditionQueries> conditions;
  size_t begin = 0;
  while (begin <= text.size()) {
    const size_t end = std::min(text.find(',', begin), text.size());
    const std::string item = text.substr(begin, end - begin);
    const size_t colon = item.find(':');
    if (colon == std::string::npos || colon == 0 || colon + 1 == item.size()) {
      ThrowInvalidArgument("conditions: expected NAME:QUERY_LIST, got '{}'", item);
    }
    conditions.push_back(ConditionFromQueryList(item.substr(0, colon), item.substr(colon + 1)));
    begin = end + 1;
  }
  return conditions;
}

std::vector<ConditionAccuracy> SummarizeAccuracyByCondition(
    const std::vector<QueryPoseError>& errors, const std::vector<ConditionQueries>& conditions,
    const std::vector<PoseThreshold>& thresholds) {
  std::vector<ConditionAccuracy> accuracies;
  for (const ConditionQueries& condition : conditions) {
    std::vector<QueryPoseError> subset;
    for (const QueryPoseError& error : errors) {
      if (condition.basenames.count(ImageBasename(error.name))) subset.push_back(error);
    }
    if (subset.size() != condition.basenames.size()) {
      ThrowInvalidArgument("condition '{}': {} of its {} queries lack ground truth", condition.name,
                           condition.basenames.size() - subset.size(), condition.basenames.size());
    }
    accuracies.push_back(SummarizeAccuracy(condition.name, std::move(subset), thresholds));
  }
  return accuracies;
}

}  // namespace hscloc
