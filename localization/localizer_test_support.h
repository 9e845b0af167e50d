// What the Localizer's tests share: query sets with their ground truth, a run over a set, and the
// fixture of the trained `small` synthetic city (built by ctest's fixture.trained_small_city).
#pragma once

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <map>
#include <string>
#include <unordered_map>
#include <vector>

#include "localization/ablation.h"
#include "localization/localizer.h"
#include "localization/pose_evaluation.h"
#include "localization/query_runner.h"
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
