// XFeat end to end on the real sets: features extracted from the photos, the map triangulated
// from the set's own poses (hscloc triangulate), built, trained, and the held-out queries localized
// from their XFeat features with the network and with the nearest-neighbour baseline. The SIFT
// path of the same sets (database.db) is localization/localizer_test.cc's RealDataLocalizerTest.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <iostream>
#include <map>

#include "features/image_extraction.h"
#include "localization/localizer.h"
#include "localization/localizer_test_support.h"
#include "model/trainer.h"
#include "scene/feature_io.h"
#include "triangulation/map_triangulation.h"
#include "util/testing.h"
#include "util/timer.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;

// Per matcher, the queries within (0.25 m, 2 deg) and within (0.5 m, 5 deg), and the median
// position error.
struct QueryCounts {
  int fine = 0;
  int medium = 0;
  double median_position = 0;
};
using CountsPerMatcher = std::map<Matcher, QueryCounts>;

// One training seed's network: its queries per matcher (the nearest-neighbour baseline retrieves
// through the network's votes when the global descriptor fails, so it is counted per seed too),
// and its held-out point accuracy beside the nearest-class-mean matcher's on the same observations.
struct SeedOutcome {
  uint64_t seed = 0;
  CountsPerMatcher counts;
  double held_out_accuracy = 0;
  double class_mean_accuracy = 0;
  size_t num_held_out = 0;
};

QueryCounts CountWithinBounds(const RunSummary& run) {
  QueryCounts counts;
  for (const QueryPoseError& error : run.accuracy.errors) {
    counts.fine += error.position <= 0.25 && error.rotation_deg <= 2.0;
    counts.medium += error.position <= 0.5 && error.rotation_deg <= 5.0;
  }
  counts.median_position = run.accuracy.median_position;
  return counts;
}

// XFeat extracted from the set's photos and its map triangulated from the set's poses, once; then
// `hscloc train`'s own network, rows per point and budget for the map with each seed (on these
// maps a row per training view, whose final pose matches the rows as nearest neighbour matches).
std::vector<SeedOutcome> LocalizeWithXFeat(const fs::path& data, const fs::path& weights,
                                           const std::vector<uint64_t>& seeds) {
  testing::TempDir temp;
  Timer step;
  ImageExtractionOptions extraction;
  extraction.extractor.type = FeatureType::kXFeat;
  extraction.extractor.xfeat.model_path = weights / "xfeat.onnx";
  extraction.show_progress = false;
  const fs::path features = temp / "features.h5";
  ExtractImagesToH5(data / "images", ListImages(data / "images"), features, extraction);
  const double extract_s = step.ElapsedSeconds();

  step.Restart();
  MapTriangulationOptions triangulation;
  triangulation.colmap.colmap_executable = *testing::ColmapExecutable();
  triangulation.show_progress = false;
  const MapTriangulationSummary triangulated =
      TriangulateMap({data / "map", features, data / "images"}, triangulation, temp / "model");
  const double triangulate_s = step.ElapsedSeconds();
  std::cout << fmt::format(
      "{}: XFeat extracted in {:.1f} s; {} pairs ({} verified), {} verified matches; {} points, "
      "mean track length {:.2f}, mean reprojection error {:.2f} px, triangulated in {:.1f} s\n",
      data.filename().string(), extract_s, triangulated.num_pairs, triangulated.num_verified_pairs,
      triangulated.num_verified_matches, triangulated.num_points3D, triangulated.mean_track_length,
      triangulated.mean_reprojection_error_px, triangulate_s);

  const auto reader = OpenH5Features(features);
  const QuerySet set =
      ReadQuerySet(data / "queries_with_intrinsics.txt", *reader, data / "queries_gt.txt");
  std::vector<SeedOutcome> outcomes;
  for (const uint64_t seed : seeds) {
    TrainerOptions training;  // as `hscloc train` trains without options: 5 % held out
    training.seed = seed;
    const TrainedRealMap trained = BuildAndTrainRealMap(
        temp / "model", features, temp / fmt::format("map-seed{}", seed), training);
    const Localizer localizer(trained.map, trained.network);
    const std::vector<uint32_t> held_out =
        HeldOutObservations(trained.map->scene(), training.holdout_fraction, training.holdout_seed);
    SeedOutcome outcome{seed, {}, trained.held_out_accuracy, 0, held_out.size()};
    outcome.class_mean_accuracy =
        EvaluateNearestClassMean(trained.map->scene(), trained.map->label_tree(),
                                 trained.map->visibility(), held_out)
            .leaf_accuracy;
    std::cout << fmt::format(
        "seed {}: {} iterations in {:.1f} s; held-out point accuracy {:.1f} %, class means "
        "{:.1f} %\n",
        seed, trained.iterations, trained.train_seconds, 100 * outcome.held_out_accuracy,
        100 * outcome.class_mean_accuracy);
    for (const Matcher matcher : {Matcher::kNetwork, Matcher::kNearestNeighbor}) {
      outcome.counts[matcher] = CountWithinBounds(LocalizeAndPrint(localizer, matcher, set));
    }
    outcomes.push_back(outcome);
  }
  return outcomes;
}

// What holds for every one of three training seeds, with margin: the set's queries within (0.25
// m, 2 deg) with the network and with the baseline, at least these many; every query within (0.5
// m, 5 deg) with both; the network's median position error within 1.25 times the baseline's (the
// final pose starts from the winner's own row matches: 1.12 to 1.13 times on Lund over seeds 1 to
// 5, with the default budget and with four minutes, where a start from the pose of the network's
// matches gave 0.98 to 1.85 times; docs/decisions.md); and the network's held-out point accuracy
// at least the nearest-class-mean matcher's. The network starts as a soft vote of each point's
// training views (its rows' log-sum-exp), 5.3 points above the class means on Lund (80.4 against
// 75.1 %) and 2.7 on fountain (89.1 against 86.4 %), 11 held-out observations or more, where a
// point's best view alone was 1.3-3 points below them; training keeps its best check. Skips
// without the set, XFeat's weights or COLMAP.
void ExpectQueriesOverSeeds(const std::string& set, int network_fine, int nearest_neighbor_fine) {
  HSCLOC_REQUIRE_REAL_DATA(data, set);
  HSCLOC_REQUIRE_REAL_DATA(weights, "weights/xfeat");
  HSCLOC_REQUIRE_COLMAP(colmap);
  const auto num_queries =
      static_cast<int>(ReadQueryList(data / "queries_with_intrinsics.txt").size());
  for (const SeedOutcome& outcome : LocalizeWithXFeat(data, weights, {1, 2, 3})) {
    SCOPED_TRACE(fmt::format("training seed {}", outcome.seed));
    CountsPerMatcher counts = outcome.counts;
    EXPECT_GE(counts[Matcher::kNetwork].fine, network_fine);
    EXPECT_GE(counts[Matcher::kNearestNeighbor].fine, nearest_neighbor_fine);
    for (const Matcher matcher : {Matcher::kNetwork, Matcher::kNearestNeighbor}) {
      EXPECT_EQ(counts[matcher].medium, num_queries) << MatcherName(matcher);
    }
    EXPECT_LE(counts[Matcher::kNetwork].median_position,
              1.25 * counts[Matcher::kNearestNeighbor].median_position);
    EXPECT_GE(outcome.held_out_accuracy, outcome.class_mean_accuracy)
        << "on " << outcome.num_held_out << " held-out observations";
  }
}

// Fountain's two queries come within 2 cm and 0.1 deg (SIFT: 2.5 mm) with every seed.
TEST(XFeatRealDataTest, FountainQueriesOverSeeds) { ExpectQueriesOverSeeds("fountain-P11", 2, 2); }

// Lund with XFeat (photos seen at 1024 px through 2 x 2 tiles): the nearest-neighbour baseline
// localizes all 5 queries within (0.25 m, 2 deg), at most 0.12 m off. The network, a row per
// training view whose final pose matches the rows as nearest neighbour matches, put every query
// within 0.12 m with seeds 1 to 5 on the machine these numbers come from (docs/decisions.md): a
// margin of twice that for another CPU, which sums in another order and trains another network
// from the same seed. With one row per point it was 4 of 5 (25.jpg, whose pose rests on a narrow
// cone of far points, up to 0.26 m off).
TEST(XFeatRealDataTest, LundQueriesOverSeeds) { ExpectQueriesOverSeeds("lund", 5, 5); }

}  // namespace
}  // namespace hscloc
