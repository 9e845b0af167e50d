#include "localization/matcher_choice.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>

#include "localization/localizer_test_support.h"
#include "map/map_bundle.h"
#include "model/network.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

nlohmann::json MetadataWith(const MatchingCost& cost) {
  return {{map_metadata::kNetwork, cost.AsNetworkNotes()}};
}

MatchingCost Cost(double network_ms, double nearest_neighbor_ms) {
  MatchingCost cost;
  cost.keypoints = 1000;
  cost.images = 10;
  cost.network_ms = network_ms;
  cost.nearest_neighbor_ms = nearest_neighbor_ms;
  return cost;
}

TEST(MatcherChoiceTest, AutoRunsTheRecordedCheaperMatcherWhereTheMapCanRunIt) {
  const nlohmann::json nearest_neighbor_cheaper = MetadataWith(Cost(30, 10));
  const nlohmann::json network_cheaper = MetadataWith(Cost(10, 30));
  EXPECT_EQ(ResolveMatcher(Matcher::kAuto, nearest_neighbor_cheaper, true, true),
            Matcher::kNearestNeighbor);
  EXPECT_EQ(ResolveMatcher(Matcher::kAuto, network_cheaper, true, true), Matcher::kNetwork);
  // A tie goes to the network.
  EXPECT_EQ(ResolveMatcher(Matcher::kAuto, MetadataWith(Cost(10, 10)), true, true),
            Matcher::kNetwork);
  // What the map cannot run is not chosen; without a record the network runs where there is one.
  EXPECT_EQ(ResolveMatcher(Matcher::kAuto, nearest_neighbor_cheaper, true, false),
            Matcher::kNetwork);
  EXPECT_EQ(ResolveMatcher(Matcher::kAuto, network_cheaper, false, true),
            Matcher::kNearestNeighbor);
  EXPECT_EQ(ResolveMatcher(Matcher::kAuto, nlohmann::json::object(), true, true),
            Matcher::kNetwork);
  // Explicit matchers are what they say.
  EXPECT_EQ(ResolveMatcher(Matcher::kNetwork, nearest_neighbor_cheaper, true, true),
            Matcher::kNetwork);
  EXPECT_EQ(ResolveMatcher(Matcher::kNearestNeighbor, network_cheaper, true, true),
            Matcher::kNearestNeighbor);
  EXPECT_THAT(DescribeAutoMatcher(Cost(30, 10), true, true),
              HasSubstr("matcher auto: nn (matching 1000 keypoints against 10 images"));
  EXPECT_THAT(DescribeAutoMatcher(std::nullopt, true, true), HasSubstr("no timing"));
  EXPECT_THAT(DescribeAutoMatcher(std::nullopt, false, true), HasSubstr("no trained network"));
}

TEST(MatcherChoiceTest, TheRecordRoundTripsAndAMalformedOneIsNone) {
  const MatchingCost cost = Cost(12.5, 3.25);
  const std::optional<MatchingCost> read = MatchingCost::FromMetadata(MetadataWith(cost));
  ASSERT_TRUE(read.has_value());
  EXPECT_EQ(read->keypoints, 1000);
  EXPECT_EQ(read->images, 10);
  EXPECT_EQ(read->network_ms, 12.5);
  EXPECT_EQ(read->nearest_neighbor_ms, 3.25);
  EXPECT_EQ(read->Cheaper(), Matcher::kNearestNeighbor);

  EXPECT_FALSE(MatchingCost::FromMetadata(nlohmann::json::object()).has_value());
  nlohmann::json negative = MetadataWith(cost);
  negative[map_metadata::kNetwork]["matching_cost"]["network_ms"] = -1;
  EXPECT_FALSE(MatchingCost::FromMetadata(negative).has_value());
  nlohmann::json missing = MetadataWith(cost);
  missing[map_metadata::kNetwork]["matching_cost"].erase("nearest_neighbor_ms");
  EXPECT_FALSE(MatchingCost::FromMetadata(missing).has_value());
  nlohmann::json wrong_type = MetadataWith(cost);
  wrong_type[map_metadata::kNetwork]["matching_cost"]["images"] = "ten";
  EXPECT_FALSE(MatchingCost::FromMetadata(wrong_type).has_value());
}

TEST(MatcherChoiceTest, MeasuresBothMatchersOnOneThreadAndRestoresTheThreads) {
  HSCLOC_REQUIRE_TRAINED_SMALL_CITY(dir);
  const auto map = LocalizationMap::Load(dir / "map", {.load_observations = true});
  ASSERT_NE(map->network(), nullptr);
  SetComputeThreads(2);
  const int threads = ComputeThreads();
  const MatchingCost cost = MeasureMatchingCost(*map, *map->network(), {}, 300, 4);
  EXPECT_EQ(ComputeThreads(), threads);
  EXPECT_EQ(cost.keypoints, 300);
  EXPECT_EQ(cost.images, 4);
  EXPECT_TRUE(std::isfinite(cost.network_ms) && cost.network_ms > 0) << cost.network_ms;
  EXPECT_TRUE(std::isfinite(cost.nearest_neighbor_ms) && cost.nearest_neighbor_ms > 0)
      << cost.nearest_neighbor_ms;
  // A probe larger than the map is the whole map.
  const MatchingCost whole = MeasureMatchingCost(*map, *map->network(), {}, 50,
                                                 static_cast<int>(map->scene().NumImages()) + 5);
  EXPECT_EQ(whole.images, static_cast<int>(map->scene().NumImages()));

  const auto without_observations = LocalizationMap::Load(dir / "map");
  EXPECT_THAT(testing::InvalidArgumentMessage(
                  [&] { MeasureMatchingCost(*without_observations, *map->network()); }),
              HasSubstr("needs the map's observations"));
}

// `hscloc train` (the fixture's) records the timing; "auto" runs what it names, and a bundle whose
// record says otherwise runs the other matcher, loading the observations only for nearest
// neighbour.
TEST(MatcherChoiceTest, AutoFollowsTheTrainedMapsRecord) {
  HSCLOC_REQUIRE_TRAINED_SMALL_CITY(dir);
  const std::optional<MatchingCost> recorded = MatchingCost::FromMetadata(
      MapBundle::Open(dir / "map", std::vector<std::string>{}).metadata());
  ASSERT_TRUE(recorded.has_value()) << "the fixture's `hscloc train` recorded no matching cost";
  EXPECT_EQ(recorded->keypoints, 1000);
  EXPECT_EQ(recorded->images, 10);

  testing::TempDir temp;
  fs::copy(dir / "map", temp / "map", fs::copy_options::recursive);
  {
    MapBundleWriter writer = MapBundleWriter::Update(temp / "map");
    writer.metadata()[map_metadata::kNetwork]["matching_cost"] =
        Cost(recorded->nearest_neighbor_ms, recorded->network_ms).ToJson();
    writer.Commit();
  }
  const std::unique_ptr<FeatureReader> features = OpenFeatureReader(dir / "city" / "features.h5");
  const std::vector<LocalizationQuery> queries =
      LoadQueries(dir / "city" / "queries" / "day_time_queries_with_intrinsics.txt", *features);
  ASSERT_FALSE(queries.empty());

  LocalizerOptions automatic;
  automatic.matcher = Matcher::kAuto;
  for (const fs::path& bundle : {dir / "map", temp / "map"}) {
    const Localizer localizer = Localizer::FromBundle(bundle, automatic);
    const Matcher expected =
        MatchingCost::FromMetadata(localizer.map().metadata()).value().Cheaper();
    EXPECT_EQ(localizer.ResolvedMatcher(Matcher::kAuto), expected) << bundle;
    EXPECT_EQ(localizer.map().scene().NumObservations() > 0, expected == Matcher::kNearestNeighbor)
        << bundle;
    LocalizerOptions explicit_options = automatic;
    explicit_options.matcher = expected;
    const PoseResult by_auto = localizer.Localize(queries[0]);
    const PoseResult by_name = localizer.Localize(queries[0], explicit_options);
    EXPECT_EQ(by_auto.num_inliers, by_name.num_inliers) << bundle;
    EXPECT_TRUE(by_auto.cam_from_world.translation.isApprox(by_name.cam_from_world.translation))
        << bundle;
  }
}

}  // namespace
}  // namespace hscloc
