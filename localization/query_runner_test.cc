#include "localization/query_runner.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <fstream>
#include <iterator>

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
