// What the Localizer's tests share: query sets with their ground truth, a run over a set, a real
// set's map built and trained, and the fixture of the trained `small` synthetic city (built by
// ctest's fixture.trained_small_city).
#pragma once

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <functional>
#include <iostream>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <unordered_map>
#include <vector>

#include "localization/ablation.h"
#include "localization/localizer.h"
#include "localization/map_builder.h"
#include "localization/pose_evaluation.h"
#include "localization/query_runner.h"
#include "model/trainer.h"
#include "scene/feature_io.h"
#include "scene/query_io.h"
#include "util/testing.h"

namespace hscloc {

// Queries with their features and ground truth.
struct QuerySet {
  std::vector<LocalizationQuery> queries;
  std::vector<NamedPose> ground_truth;
};

inline QuerySet ReadQuerySet(const std::filesystem::path& list, const FeatureReader& features,
                             const std::filesystem::path& ground_truth) {
  QuerySet set;
  std::unordered_map<std::string, Rigid3d> truth;
  for (const NamedPose& pose : ReadPoses(ground_truth)) truth[pose.name] = pose.cam_from_world;
  set.queries = LoadQueries(list, features);
  for (const LocalizationQuery& query : set.queries) {
    set.ground_truth.push_back({query.name, truth.at(query.name)});
  }
  return set;
}

// Whether the result is a pose within (0.25 m, 2 deg) of the truth, Aachen's finest bound.
inline bool WithinQuarterMetreAndTwoDegrees(const NamedPose& truth, const PoseResult& result) {
  if (!result.success) return false;
  const std::vector<QueryPoseError> errors =
      ComputePoseErrors({truth}, {{truth.name, result.cam_from_world}});
  return errors.size() == 1 && errors[0].position < 0.25 && errors[0].rotation_deg < 2;
}

struct RunSummary {
  ConditionAccuracy accuracy;
  std::vector<PoseResult> results;
  StageTimings mean_timings;
  double mean_candidates_evaluated = 0;
};

inline RunSummary LocalizeAll(const Localizer& localizer, const LocalizerOptions& options,
                              const QuerySet& set, const std::string& condition) {
  RunSummary summary;
  std::vector<NamedPose> estimates;
  StageTimingAccumulator timings;
  for (const LocalizationQuery& query : set.queries) {
    PoseResult result = localizer.Localize(query, options);
    if (result.success) estimates.push_back({query.name, result.cam_from_world});
    timings.Add(result.timings);
    for (const LocalizationCandidate& candidate : result.candidates) {
      summary.mean_candidates_evaluated += candidate.evaluated / double(set.queries.size());
    }
    summary.results.push_back(std::move(result));
  }
  summary.mean_timings = timings.Mean();
  summary.accuracy = SummarizeAccuracy(condition, ComputePoseErrors(set.ground_truth, estimates),
                                       AachenThresholds());
  return summary;
}

// A real set's map: built from a COLMAP model and its features, and trained with the widths and
// the rows per point `hscloc train` chooses for it, or `point_prototypes` rows per point where
// given; `training` gives the budget and the held-out fraction.
struct TrainedRealMap {
  std::shared_ptr<const LocalizationMap> map;
  std::shared_ptr<const Network> network;
  int64_t iterations = 0;
  double train_seconds = 0;
  double held_out_accuracy = -1;  // the kept network's, -1 when never evaluated
};

inline TrainedRealMap BuildAndTrainRealMap(const std::filesystem::path& model,
                                           const std::filesystem::path& features,
                                           const std::filesystem::path& bundle,
                                           TrainerOptions training,
                                           std::optional<int> point_prototypes = std::nullopt) {
  MapBuildOptions build_options;
  build_options.show_progress = false;
  build_options.label_tree.show_progress = false;
  BuildMap({model, features, std::nullopt}, build_options, bundle);
  TrainedRealMap trained;
  trained.map = LocalizationMap::Load(bundle, {.load_observations = true});
  training.network = DefaultNetworkOptions(trained.map->scene().NumPoints(),
                                           static_cast<int>(trained.map->scene().Dimension()));
  training.point_prototypes = point_prototypes.value_or(DefaultPointPrototypes(training.network));
  training.show_progress = false;
  TrainingResult result = TrainNetwork(trained.map->scene(), trained.map->label_tree(), training);
  trained.network = std::make_shared<const Network>(std::move(result.network));
  trained.iterations = result.iterations;
  trained.train_seconds = result.seconds;
  trained.held_out_accuracy = result.best_held_out_accuracy;
  return trained;
}

// LocalizeAll with `matcher`, printing each query's errors and inliers, and `note(i)` after
// query i's when given.
inline RunSummary LocalizeAndPrint(const Localizer& localizer, Matcher matcher, const QuerySet& set,
                                   const std::function<std::string(size_t)>& note = {}) {
  LocalizerOptions options;
  options.matcher = matcher;
  RunSummary run = LocalizeAll(localizer, options, set, MatcherName(matcher));
  for (size_t i = 0; i < set.queries.size(); ++i) {
    const QueryPoseError& error = run.accuracy.errors[i];
    std::cout << fmt::format(
        "  {:<4} {:<9} position error {:8.4f}  rotation error {:7.3f} deg  inliers {:4}{}\n",
        MatcherName(matcher), set.queries[i].name, error.position, error.rotation_deg,
        run.results[i].num_inliers, note ? "  " + note(i) : "");
  }
  return run;
}

// The trained `small` synthetic city of the test fixture.

class SmallCityLocalizerTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    const auto dir = testing::TrainedSmallCityDir();
    if (!dir) return;
    auto map = LocalizationMap::Load(*dir / "map", {.load_observations = true});
    localizer_ = new Localizer(map, map->network());
    const auto features = OpenH5Features(*dir / "city" / "features.h5");
    for (const char* condition : {"day", "night"}) {
      sets_[condition] = ReadQuerySet(
          *dir / "city" / "queries" / fmt::format("{}_time_queries_with_intrinsics.txt", condition),
          *features, *dir / "city" / "queries_gt.txt");
    }
  }
  static void TearDownTestSuite() {
    delete localizer_;
    localizer_ = nullptr;
  }
  void SetUp() override {
    if (localizer_ == nullptr) {
      GTEST_SKIP() << "the trained small city is missing: run the tests through ctest, whose "
                      "fixture.trained_small_city builds it";
    }
  }

  static const Localizer& localizer() { return *localizer_; }
  static const QuerySet& Set(const std::string& condition) { return sets_.at(condition); }
  // The day and night sets as the ablation runner takes them, and their ground truth.
  static std::vector<AblationQuerySet> AblationSets() {
    return {{"day", Set("day").queries}, {"night", Set("night").queries}};
  }
  static std::vector<NamedPose> GroundTruth() {
    std::vector<NamedPose> truth = Set("day").ground_truth;
    truth.insert(truth.end(), Set("night").ground_truth.begin(), Set("night").ground_truth.end());
    return truth;
  }

 private:
  static inline Localizer* localizer_ = nullptr;
  static inline std::map<std::string, QuerySet> sets_;
};

}  // namespace hscloc
