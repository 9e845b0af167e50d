// Accuracy of estimated poses against ground truth, as visuallocalization.net reports it: the share
// of queries localized within (position, rotation) thresholds, per condition (day, night), and
// median errors. Queries without an estimate count as failures at every threshold.
#pragma once

#include <filesystem>
#include <limits>
#include <string>
#include <unordered_set>
#include <vector>

#include "scene/query_io.h"

namespace hscloc {

struct PoseThreshold {
  double position = 0;      // world units (metres)
  double rotation_deg = 0;  // degrees
};

// The Aachen Day-Night thresholds: (0.25 m, 2 deg), (0.5 m, 5 deg), (5 m, 10 deg).
std::vector<PoseThreshold> AachenThresholds();

struct QueryPoseError {
  std::string name;  // as in the ground truth
  bool estimated = false;
  double position = std::numeric_limits<double>::infinity();
  double rotation_deg = std::numeric_limits<double>::infinity();
};

// Matches results to ground truth by image basename (submissions carry basenames). Throws
// std::invalid_argument when two ground-truth or two result names share a basename, or a result
// names a query the ground truth lacks.
std::vector<QueryPoseError> ComputePoseErrors(const std::vector<NamedPose>& ground_truth,
                                              const std::vector<NamedPose>& results);

struct ConditionAccuracy {
  std::string condition;
  size_t num_queries = 0;
  size_t num_estimated = 0;
  std::vector<PoseThreshold> thresholds;
  std::vector<double> localized_fraction;  // per threshold, in [0, 1]
  // Medians over all queries (a missing estimate is an infinite error).
  double median_position = std::numeric_limits<double>::infinity();
  double median_rotation_deg = std::numeric_limits<double>::infinity();
  std::vector<QueryPoseError> errors;  // the queries of this condition
};

ConditionAccuracy SummarizeAccuracy(const std::string& condition,
                                    std::vector<QueryPoseError> errors,
                                    const std::vector<PoseThreshold>& thresholds);

// A named subset of the queries (a condition: day, night), by image basename.
struct ConditionQueries {
  std::string name;
  std::unordered_set<std::string> basenames;
};
// The condition made of the queries of an Aachen query list.
ConditionQueries ConditionFromQueryList(const std::string& name, const std::filesystem::path& list);
// "day:LIST,night:LIST" -> one condition per item; throws std::invalid_argument naming the item
// that is not NAME:LIST.
std::vector<ConditionQueries> ParseConditions(const std::string& text);

// One ConditionAccuracy per condition, over the errors of its queries. Throws
// std::invalid_argument when queries of a condition have no ground truth (no error entry).
std::vector<ConditionAccuracy> SummarizeAccuracyByCondition(
    const std::vector<QueryPoseError>& errors, const std::vector<ConditionQueries>& conditions,
    const std::vector<PoseThreshold>& thresholds);

// A plain-text table, one row per condition:
//   condition  queries  (0.25 m, 2 deg)  (0.5 m, 5 deg)  (5 m, 10 deg)  median position / rotation
std::string FormatAccuracyTable(const std::vector<ConditionAccuracy>& accuracies);

}  // namespace hscloc
