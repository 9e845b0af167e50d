#include "bench/query_evaluation.h"

#include <algorithm>
#include <map>
#include <string>

#include "model/network.h"
#include "util/parallel.h"
#include "util/random.h"
#include "util/statistics.h"

namespace hscloc::bench {

using nlohmann::json;

LocalizationQuery WithKeypointCount(const LocalizationQuery& query, int64_t count, uint64_t seed) {
  LocalizationQuery result = query;
  const int64_t own = std::min<int64_t>(count, query.keypoints.rows());
  const int64_t dim = query.descriptors.cols();
  result.keypoints.resize(count, 2);
  result.descriptors.resize(count, dim);
  result.keypoints.topRows(own) = query.keypoints.topRows(own);
  result.descriptors.topRows(own) = query.descriptors.topRows(own);
  Random random(seed);
  for (int64_t i = own; i < count; ++i) {
    result.keypoints(i, 0) = static_cast<float>(random.Uniform(0, query.camera.width));
    result.keypoints(i, 1) = static_cast<float>(random.Uniform(0, query.camera.height));
    for (int64_t j = 0; j < dim; ++j) result.descriptors(i, j) = float(random.Normal());
    result.descriptors.row(i).normalize();
  }
  return result;
}

Evaluation Evaluate(const Localizer& localizer, const LocalizerOptions& options,
                    const std::vector<LocalizationQuery>& queries,
                    const std::vector<NamedPose>& ground_truth, const std::string& condition) {
  SetComputeThreads(1);
  Evaluation evaluation;
  evaluation.results.resize(queries.size());
  for (const LocalizationQuery& query : queries)
    evaluation.keypoints.push_back(query.keypoints.rows());
  ParallelFor(queries.size(), 0, [&](size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i) {
      evaluation.results[i] = localizer.Localize(queries[i], options);
    }
  });
  std::vector<NamedPose> estimates;
  std::vector<NamedPose> truth;
  for (size_t i = 0; i < queries.size(); ++i) {
    estimates.push_back({queries[i].name, evaluation.results[i].cam_from_world});
    const std::string basename = ImageBasename(queries[i].name);
    for (const NamedPose& pose : ground_truth) {
      if (ImageBasename(pose.name) == basename) truth.push_back(pose);
    }
  }
  evaluation.accuracy =
      SummarizeAccuracy(condition, ComputePoseErrors(truth, estimates), AachenThresholds());
  return evaluation;
}

json AccuracyJson(const Evaluation& evaluation) {
  std::vector<double> total_ms;
  for (const PoseResult& result : evaluation.results) total_ms.push_back(result.timings.total_ms);
  return {{"queries", evaluation.accuracy.num_queries},
          {"localized_fraction", evaluation.accuracy.localized_fraction},
          {"median_position", evaluation.accuracy.median_position},
          {"median_rotation_deg", evaluation.accuracy.median_rotation_deg},
          {"ms_per_query_one_thread", Mean(total_ms)},
          {"timings", StageTimingsJson(evaluation)},
          {"per_query", PerQueryErrorsJson(evaluation.accuracy)}};
}

namespace {

std::string QueryClass(const PoseResult& result, int64_t keypoints) {
  const bool last_resort = std::any_of(result.candidates.begin(), result.candidates.end(),
                                       [](const LocalizationCandidate& candidate) {
                                         return candidate.source == CandidateSource::kNearestPoints;
                                       });
  const std::string rounds = last_resort                 ? "points' last round"
                             : result.timings.rounds > 1 ? "votes' round"
                                                         : "one round";
  const std::string size = keypoints < 1000   ? "< 1000 keypoints"
                           : keypoints < 3000 ? "1000-2999 keypoints"
                                              : ">= 3000 keypoints";
  return rounds + ", " + size;
}

json Percentiles(const std::vector<double>& ms) {
  return {{"mean", Mean(ms)},
          {"p50", Percentile(ms, 0.5)},
          {"p95", Percentile(ms, 0.95)},
          {"max", Percentile(ms, 1.0)}};
}

}  // namespace

json StageTimingsJson(const Evaluation& evaluation) {
  StageTimingAccumulator timings;
  for (const PoseResult& result : evaluation.results) timings.Add(result.timings);
  json stages = json::object();
  for (const StageField& field : kStageFields) {
    std::vector<double> ms;
    for (const StageTimings& one : timings.all()) ms.push_back(one.*field.milliseconds);
    stages[std::string(field.name)] = Percentiles(ms);
  }
  // The slowest 5 % (at least one query), and each class's share of them.
  const double tail_from = timings.count() == 0 ? 0 : timings.TotalPercentileMs(0.95);
  std::map<std::string, std::vector<double>> by_class;
  std::map<std::string, int> in_tail;
  for (size_t i = 0; i < evaluation.results.size(); ++i) {
    const PoseResult& result = evaluation.results[i];
    const std::string name = QueryClass(result, evaluation.keypoints[i]);
    by_class[name].push_back(result.timings.total_ms);
    in_tail[name] += result.timings.total_ms >= tail_from;
  }
  json classes = json::array();
  for (const auto& [name, ms] : by_class) {
    json entry = Percentiles(ms);
    entry["class"] = name;
    entry["queries"] = ms.size();
    entry["in_slowest_5_percent"] = in_tail[name];
    classes.push_back(entry);
  }
  return {{"stages", stages}, {"classes", classes}};
}

json PerQueryErrorsJson(const ConditionAccuracy& accuracy) {
  json queries = json::array();
  for (const QueryPoseError& error : accuracy.errors) {
    json entry = {{"name", error.name}, {"position", nullptr}, {"rotation_deg", nullptr}};
    if (error.estimated) {
      entry["position"] = error.position;
      entry["rotation_deg"] = error.rotation_deg;
    }
    queries.push_back(entry);
  }
  return queries;
}

}  // namespace hscloc::bench
