// Localizing a benchmark's query sets and scoring them, as `hscloc localize` and `hscloc eval` do.
#pragma once

#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "localization/localizer.h"
#include "localization/pose_evaluation.h"
#include "scene/query_io.h"

namespace hscloc::bench {

// The query with exactly `count` keypoints: its own (the first `count` when it has more), then
// clutter keypoints, uniform in the image with random unit descriptors, as a detector tuned to
// return `count` keypoints would add.
LocalizationQuery WithKeypointCount(const LocalizationQuery& query, int64_t count, uint64_t seed);

struct Evaluation {
  ConditionAccuracy accuracy;
  std::vector<PoseResult> results;
  std::vector<int64_t> keypoints;  // each query's
};

// Localizes the queries, each on one thread and several at a time (as `hscloc localize` does),
// and scores them against the ground truth.
Evaluation Evaluate(const Localizer& localizer, const LocalizerOptions& options,
                    const std::vector<LocalizationQuery>& queries,
                    const std::vector<NamedPose>& ground_truth, const std::string& condition);

// Accuracy per threshold, medians, the mean time per query, and each query's errors.
nlohmann::json AccuracyJson(const Evaluation& evaluation);

// Where the time goes: each stage's mean, p50, p95 and max milliseconds per query ("stages"), and
// the queries by class (with or without the votes' round, by keypoint count) with their p50, p95
// and max, and how many of the slowest 5 % each holds ("classes").
nlohmann::json StageTimingsJson(const Evaluation& evaluation);

// Each query's name and errors (position, rotation_deg; null where it has no pose), in order.
nlohmann::json PerQueryErrorsJson(const ConditionAccuracy& accuracy);

}  // namespace hscloc::bench
