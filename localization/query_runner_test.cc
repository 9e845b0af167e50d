#include "localization/query_runner.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <fstream>
#include <iterator>
#include <sstream>

#include "localization/map_builder.h"
#include "localization/pose_evaluation.h"
#include "synthetic/synthetic_city.h"
#include "synthetic/synthetic_city_writer.h"
#include "util/testing.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

std::string ReadText(const fs::path& path) {
  std::ifstream file(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(file), std::istreambuf_iterator<char>()};
}

// The tiny synthetic city with its map, localized by the nearest-neighbour matcher (no network
// to train), written once for the suite.
class QueryRunnerTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new testing::TempDir();
    SyntheticCityWriteOptions write_options;
    write_options.show_progress = false;
    WriteSyntheticCity(SyntheticCity(SyntheticCityOptions::Preset("tiny")), City(), write_options);
    MapBuildOptions build_options;
    build_options.show_progress = false;
    build_options.label_tree.show_progress = false;
    BuildMap({City() / "map", City() / "features.h5", std::nullopt}, build_options, Bundle());
  }
  static void TearDownTestSuite() { delete dir_; }
  static fs::path City() { return dir_->path() / "city"; }
  static fs::path Bundle() { return dir_->path() / "bundle"; }
  static fs::path DayList() { return City() / "queries" / "day_time_queries_with_intrinsics.txt"; }

  static Localizer NearestNeighborLocalizer() {
    LocalizerOptions options;
    options.matcher = Matcher::kNearestNeighbor;
    return Localizer::FromBundle(Bundle(), options);
  }

  testing::TempDir temp_;

 private:
  static testing::TempDir* dir_;
};
testing::TempDir* QueryRunnerTest::dir_ = nullptr;

TEST_F(QueryRunnerTest, LoadQueriesKeepsListOrderAndFeatures) {
  const auto features = OpenFeatureReader(City() / "features.h5");
  const std::vector<QueryWithIntrinsics> list = ReadQueryList(DayList());
  ASSERT_GE(list.size(), 3u);
  const std::vector<LocalizationQuery> queries = LoadQueries(DayList(), *features);
  ASSERT_EQ(queries.size(), list.size());
  for (size_t i = 0; i < list.size(); ++i) {
    EXPECT_EQ(queries[i].name, list[i].name);
    const ImageFeatures image = features->Read(list[i].name);
    EXPECT_EQ(queries[i].keypoints, image.keypoints);
    EXPECT_EQ(queries[i].descriptors, image.descriptors);
    EXPECT_FALSE(queries[i].global_descriptor.has_value());
  }
  EXPECT_EQ(LoadQueries(DayList(), *features, nullptr, 2).size(), 2u);
}

TEST_F(QueryRunnerTest, LoadQueriesNamesAQueryWithoutFeaturesAndItsList) {
  const auto features = OpenFeatureReader(City() / "features.h5");
  const fs::path list = temp_.path() / "list.txt";
  std::ofstream(list) << "no/such/image.jpg SIMPLE_PINHOLE 640 480 500 320 240\n";
  try {
    LoadQueries(list, *features);
    FAIL() << "no exception";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("no/such/image.jpg"));
    EXPECT_THAT(error.what(), HasSubstr(list.string()));
  }
  GlobalDescriptorMap no_globals;
  EXPECT_THROW(LoadQueries(DayList(), *features, &no_globals), std::invalid_argument);
}

TEST_F(QueryRunnerTest, ResumedRunWritesWhatAnUninterruptedRunWrites) {
  const Localizer localizer = NearestNeighborLocalizer();
  const auto features = OpenFeatureReader(City() / "features.h5");
  const std::vector<QueryWithIntrinsics> queries = ReadQueryList(DayList());
  QueryListRunOptions options;
  options.show_progress = false;
  options.num_threads = 1;  // one thread: lines in list order, comparable byte for byte
  options.out = temp_.path() / "full.txt";
  const QueryListRunSummary full = RunQueryList(localizer, queries, *features, nullptr, options);
  EXPECT_EQ(full.num_queries, queries.size());
  EXPECT_EQ(full.num_skipped, 0u);
  EXPECT_EQ(full.num_localized + full.num_failed, queries.size());
  EXPECT_GT(full.num_localized, queries.size() / 2);
  EXPECT_EQ(full.timings.count(), queries.size());
  const std::string full_text = ReadText(options.out);

  // An interrupted run: two whole lines and half of the third.
  options.out = temp_.path() / "resumed.txt";
  size_t cut = 0;
  for (int line = 0; line < 2; ++line) cut = full_text.find('\n', cut) + 1;
  std::ofstream(options.out, std::ios::binary) << full_text.substr(0, cut + 5);
  options.resume = true;
  const QueryListRunSummary resumed = RunQueryList(localizer, queries, *features, nullptr, options);
  EXPECT_EQ(resumed.num_skipped, 2u);
  EXPECT_EQ(resumed.timings.count(), queries.size() - 2);
  EXPECT_EQ(ReadText(options.out), full_text);
}

TEST_F(QueryRunnerTest, TimingsFileHasALineOfStagesPerQueryAndResumesAfterTheFirst) {
  const Localizer localizer = NearestNeighborLocalizer();
  const auto features = OpenFeatureReader(City() / "features.h5");
  const std::vector<QueryWithIntrinsics> queries = ReadQueryList(DayList());
  ASSERT_GE(queries.size(), 3u);
  QueryListRunOptions options;
  options.show_progress = false;
  options.num_threads = 1;
  options.out = temp_.path() / "poses.txt";
  options.timings_out = temp_.path() / "timings" / "poses.csv";
  const std::vector<QueryWithIntrinsics> first_two(queries.begin(), queries.begin() + 2);
  RunQueryList(localizer, first_two, *features, nullptr, options);
  options.resume = true;
  const QueryListRunSummary summary = RunQueryList(localizer, queries, *features, nullptr, options);

  std::ifstream file(options.timings_out);
  std::string line;
  ASSERT_TRUE(std::getline(file, line));
  EXPECT_EQ(line,
            "name,localized,keypoints,rounds,inliers,ransac_samples,retrieval_ms,votes_ms,"
            "match_ms,"
            "visibility_ms,pose_ms,refine_ms,total_ms");
  size_t rows = 0;
  while (std::getline(file, line)) {
    std::vector<std::string> cells;
    std::stringstream stream(line);
    for (std::string cell; std::getline(stream, cell, ',');) cells.push_back(cell);
    ASSERT_EQ(cells.size(), 13u) << line;
    EXPECT_EQ(cells[0], ImageBasename(queries[rows].name));
    const LocalizationQuery query = LoadQuery(queries[rows], *features);
    EXPECT_EQ(std::stol(cells[2]), query.keypoints.rows());
    // Without a network there is no votes' round: the first, and a deeper global one where the
    // first was weak.
    EXPECT_GE(std::stoi(cells[3]), 1);
    EXPECT_LE(std::stoi(cells[3]), 2);
    // A query with a pose drew at least one sample; none draws more than its candidates' budgets.
    const int64_t samples = std::stoll(cells[5]);
    if (cells[1] == "1") {
      EXPECT_GE(samples, 1) << line;
    }
    const LocalizerOptions& defaults = localizer.options();
    EXPECT_LE(samples, int64_t{2 * defaults.top_k + defaults.deeper_global_candidates} *
                           defaults.pose.max_iterations);
    const double total = std::stod(cells[12]);
    EXPECT_GT(total, 0);
    double stages = 0;
    for (const int stage : {6, 8, 9, 10}) stages += std::stod(cells[stage]);
    EXPECT_LE(stages, total + 0.01);
    EXPECT_LE(std::stod(cells[11]), std::stod(cells[10]) + 0.001) << "refinement is part of pose";
    ++rows;
  }
  EXPECT_EQ(rows, queries.size()) << "no header again, no query twice";
  EXPECT_EQ(summary.timings.count(), queries.size() - 2);
  const std::string table = FormatStageTable(summary.timings);
  EXPECT_THAT(table, HasSubstr("p95"));
  for (const StageField& field : kStageFields) EXPECT_THAT(table, HasSubstr(field.name));
}

TEST(StageTimingAccumulatorTest, MeansAndPercentilesPerStage) {
  StageTimingAccumulator timings;
  EXPECT_TRUE(std::isnan(timings.TotalPercentileMs(0.5)));
  EXPECT_EQ(timings.Mean().total_ms, 0);
  for (int i = 1; i <= 5; ++i) {
    StageTimings one;
    one.retrieval_ms = i;
    one.votes_ms = i == 5 ? 4 : 0;
    one.total_ms = 10 * i;
    one.rounds = i == 5 ? 2 : 1;
    timings.Add(one);
  }
  EXPECT_DOUBLE_EQ(timings.Mean().retrieval_ms, 3);
  EXPECT_DOUBLE_EQ(timings.Mean().votes_ms, 0.8);
  EXPECT_EQ(timings.Mean().rounds, 1);
  EXPECT_DOUBLE_EQ(timings.TotalPercentileMs(0.5), 30);
  EXPECT_DOUBLE_EQ(timings.PercentileMs(&StageTimings::retrieval_ms, 1.0), 5);
  EXPECT_DOUBLE_EQ(timings.PercentileMs(&StageTimings::votes_ms, 0.5), 0);
}

TEST_F(QueryRunnerTest, AccuracyByConditionSplitsTheErrorsByList) {
  const std::vector<NamedPose> ground_truth = ReadPoses(City() / "queries_gt.txt");
  const std::vector<QueryWithIntrinsics> day = ReadQueryList(DayList());
  // Estimates: the ground truth itself for the day queries, nothing for the night ones.
  std::vector<NamedPose> estimates;
  for (const NamedPose& pose : ground_truth) {
    for (const QueryWithIntrinsics& query : day) {
      if (ImageBasename(query.name) == ImageBasename(pose.name)) estimates.push_back(pose);
    }
  }
  const std::vector<ConditionQueries> conditions = {
      ConditionFromQueryList("day", DayList()),
      ConditionFromQueryList("night",
                             City() / "queries" / "night_time_queries_with_intrinsics.txt")};
  const std::vector<ConditionAccuracy> accuracies = SummarizeAccuracyByCondition(
      ComputePoseErrors(ground_truth, estimates), conditions, AachenThresholds());
  ASSERT_EQ(accuracies.size(), 2u);
  EXPECT_EQ(accuracies[0].condition, "day");
  EXPECT_EQ(accuracies[0].num_queries, day.size());
  EXPECT_DOUBLE_EQ(accuracies[0].localized_fraction[0], 1.0);
  EXPECT_EQ(accuracies[1].condition, "night");
  EXPECT_GT(accuracies[1].num_queries, 0u);
  EXPECT_DOUBLE_EQ(accuracies[1].localized_fraction[2], 0.0);

  const ConditionQueries unknown{"unknown", {"not-a-query.jpg"}};
  EXPECT_THROW(SummarizeAccuracyByCondition(ComputePoseErrors(ground_truth, estimates), {unknown},
                                            AachenThresholds()),
               std::invalid_argument);
  EXPECT_THROW(ParseConditions("day"), std::invalid_argument);
  EXPECT_THROW(ParseConditions(":list.txt"), std::invalid_argument);
}

}  // namespace
}  // namespace hscloc
