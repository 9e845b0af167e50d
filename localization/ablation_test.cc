#include "localization/ablation.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "localization/map_builder.h"
#include "localization/query_runner.h"
#include "scene/feature_io.h"
#include "synthetic/synthetic_city.h"
#include "synthetic/synthetic_city_writer.h"
#include "util/testing.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

// The tiny synthetic city, mapped, with a nearest-neighbour Localizer (no network to train) and
// its day and night query sets; built once for the suite.
class AblationTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new testing::TempDir();
    SyntheticCityWriteOptions write_options;
    write_options.show_progress = false;
    WriteSyntheticCity(SyntheticCity(SyntheticCityOptions::Preset("tiny")), *dir_ / "city",
                       write_options);
    const fs::path city = *dir_ / "city";
    MapBuildOptions build_options;
    build_options.show_progress = false;
    build_options.label_tree.show_progress = false;
    BuildMap({city / "map", city / "features.h5", std::nullopt}, build_options, *dir_ / "map");
    const auto map = LocalizationMap::Load(*dir_ / "map", {.load_observations = true});
    localizer_ = new Localizer(map, nullptr, NearestNeighbor());
    const auto features = OpenFeatureReader(city / "features.h5");
    sets_ = new std::vector<AblationQuerySet>();
    for (const char* condition : {"day", "night"}) {
      sets_->push_back({condition, LoadQueries(city / "queries" /
                                                   (std::string(condition) +
                                                    "_time_queries_with_intrinsics.txt"),
                                               *features)});
    }
    truth_ = new std::vector<NamedPose>(ReadPoses(city / "queries_gt.txt"));
  }
  static void TearDownTestSuite() {
    delete localizer_;
    delete sets_;
    delete truth_;
    delete dir_;
  }

  // One retrieval round, so that each variant poses exactly its top_k.
  static LocalizerOptions NearestNeighbor() {
    LocalizerOptions options;
    options.matcher = Matcher::kNearestNeighbor;
    options.retrieval = RetrievalMode::kGlobal;
    return options;
  }
  static std::vector<AblationVariant> Variants() {
    std::vector<AblationVariant> variants = {{"top-10", NearestNeighbor()},
                                             {"top-1", NearestNeighbor()},
                                             {"top-10, no filter", NearestNeighbor()}};
    variants[1].options.top_k = 1;
    variants[2].options.visibility_filter = false;
    return variants;
  }

  static Localizer* localizer_;
  static std::vector<AblationQuerySet>* sets_;
  static std::vector<NamedPose>* truth_;

 private:
  static testing::TempDir* dir_;
};
Localizer* AblationTest::localizer_ = nullptr;
std::vector<AblationQuerySet>* AblationTest::sets_ = nullptr;
std::vector<NamedPose>* AblationTest::truth_ = nullptr;
testing::TempDir* AblationTest::dir_ = nullptr;

TEST_F(AblationTest, OneCellPerVariantAndConditionWithWhatEachSwitchActsOn) {
  AblationOptions options;
  options.keep_results = true;
  const AblationResults results = RunAblations(*localizer_, *sets_, *truth_, Variants(), options);
  EXPECT_THAT(results.variants, ::testing::ElementsAre("top-10", "top-1", "top-10, no filter"));
  EXPECT_THAT(results.conditions, ::testing::ElementsAre("day", "night"));
  ASSERT_EQ(results.cells.size(), 6u);
  const size_t num_images = localizer_->map().scene().NumImages();
  for (size_t v = 0; v < results.variants.size(); ++v) {
    for (size_t c = 0; c < results.conditions.size(); ++c) {
      const AblationCell& cell = results.cells[v * results.conditions.size() + c];
      EXPECT_EQ(&cell, &results.At(results.variants[v], results.conditions[c]));
      const size_t num_queries = (*sets_)[c].queries.size();
      EXPECT_EQ(cell.accuracy.num_queries, num_queries);
      EXPECT_EQ(cell.accuracy.condition, results.conditions[c]);
      EXPECT_EQ(cell.timings.count(), num_queries);
      ASSERT_EQ(cell.results.size(), num_queries);
      size_t successes = 0;
      for (const PoseResult& result : cell.results) successes += result.success;
      EXPECT_EQ(cell.accuracy.num_estimated, successes);
      const double top_k = v == 1 ? 1.0 : static_cast<double>(std::min<size_t>(10, num_images));
      EXPECT_DOUBLE_EQ(cell.mean_candidates, top_k);
      EXPECT_DOUBLE_EQ(cell.mean_candidates_evaluated, top_k);  // every candidate is posed
      EXPECT_GT(cell.mean_matches, 0);
    }
  }
  // The day queries of the tiny city localize with nearest neighbours; the filter only removes.
  EXPECT_GE(results.At("top-10", "day").accuracy.localized_fraction.back(), 0.8);
  for (const char* condition : {"day", "night"}) {
    EXPECT_GE(results.At("top-10, no filter", condition).mean_matches,
              results.At("top-10", condition).mean_matches);
  }
}

TEST_F(AblationTest, SummariesWithoutResultsUnlessAsked) {
  const AblationResults results =
      RunAblations(*localizer_, {sets_->front()}, *truth_, {Variants().front()});
  ASSERT_EQ(results.cells.size(), 1u);
  EXPECT_TRUE(results.cells.front().results.empty());
  EXPECT_EQ(results.cells.front().timings.count(), sets_->front().queries.size());
}

TEST_F(AblationTest, BadInputsAreRejectedByName) {
  const auto message =
      [&](const std::vector<AblationQuerySet>& sets, const std::vector<NamedPose>& truth,
          const std::vector<AblationVariant>& variants, const AblationOptions& options = {}) {
        return testing::InvalidArgumentMessage(
            [&] { RunAblations(*localizer_, sets, truth, variants, options); });
      };
  const std::vector<AblationQuerySet> day = {sets_->front()};
  EXPECT_THAT(message(day, *truth_, {}), HasSubstr("no variants"));
  EXPECT_THAT(message({}, *truth_, Variants()), HasSubstr("no query sets"));
  EXPECT_THAT(message(day, *truth_, {Variants()[0], Variants()[0]}), HasSubstr("'top-10'"));
  EXPECT_THAT(message({day[0], day[0]}, *truth_, Variants()), HasSubstr("'day'"));
  std::vector<AblationVariant> bad = {Variants()[0]};
  bad[0].options.top_k = 0;
  EXPECT_THAT(message(day, *truth_, bad), HasSubstr("top_k"));
  AblationOptions no_thresholds;
  no_thresholds.thresholds.clear();
  EXPECT_THAT(message(day, *truth_, Variants(), no_thresholds), HasSubstr("thresholds"));
  // A query without ground truth.
  std::vector<NamedPose> partial(truth_->begin() + 1, truth_->end());
  std::vector<AblationQuerySet> first_query = {{"day", {day[0].queries.front()}}};
  const std::string missing = ImageBasename(truth_->front().name);
  ASSERT_EQ(ImageBasename(first_query[0].queries[0].name), missing);
  EXPECT_THAT(message(first_query, partial, {Variants()[0]}), HasSubstr("ground truth"));

  const AblationResults results = RunAblations(*localizer_, day, *truth_, {Variants()[0]});
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { results.At("top-1", "day"); }),
              HasSubstr("'top-1'"));
}

TEST(AblationVariantsTest, ThePaperFirstThenOneSwitchEach) {
  const std::vector<AblationVariant> variants = StandardAblationVariants();
  ASSERT_EQ(variants.size(), 7u);
  const LocalizerOptions defaults;
  EXPECT_EQ(variants[0].options.top_k, defaults.top_k);
  EXPECT_EQ(variants[0].options.top_k, 10);
  for (size_t i = 0; i < 5; ++i) {
    EXPECT_EQ(variants[i].options.retrieval, RetrievalMode::kGlobal) << variants[i].name;
  }
  for (size_t i = 0; i < 6; ++i) {
    EXPECT_EQ(variants[i].options.final_pose, FinalPose::kWinner) << variants[i].name;
  }
  EXPECT_EQ(variants[5].options.retrieval, RetrievalMode::kGlobalThenVotes);
  EXPECT_EQ(variants[6].options.retrieval, defaults.retrieval);
  EXPECT_EQ(variants[6].options.final_pose, defaults.final_pose);
  EXPECT_EQ(variants[6].options.final_pose, FinalPose::kPooled);
  EXPECT_TRUE(variants[0].options.visibility_filter);
  EXPECT_FALSE(variants[0].options.visibility_masked_decoding);
  EXPECT_EQ(variants[1].options.top_k, 1);
  EXPECT_FALSE(variants[2].options.visibility_filter);
  EXPECT_EQ(variants[3].options.top_k, 1);
  EXPECT_FALSE(variants[3].options.visibility_filter);
  EXPECT_TRUE(variants[4].options.visibility_masked_decoding);
  for (const AblationVariant& variant : variants) EXPECT_NO_THROW(variant.options.Check());
}

TEST(AblationTextTest, TablesNameEveryVariantAndCondition) {
  AblationResults results;
  results.variants = {"a", "b"};
  results.conditions = {"day"};
  for (const char* variant : {"a", "b"}) {
    AblationCell cell;
    cell.variant = variant;
    cell.condition = "day";
    cell.accuracy = SummarizeAccuracy("day", {}, AachenThresholds());
    cell.timings.Add({1, 2, 3, 4, 10});
    results.cells.push_back(cell);
  }
  const std::string text = FormatAblationTable(results);
  EXPECT_THAT(text, HasSubstr("a\ncondition"));
  EXPECT_THAT(text, HasSubstr("b\ncondition"));
  EXPECT_THAT(FormatLatencyTable(results, "b"),
              HasSubstr("| day | 1.0 | 2.0 | 3.00 | 4.0 | 10.0 |"));
}

}  // namespace
}  // namespace hscloc
