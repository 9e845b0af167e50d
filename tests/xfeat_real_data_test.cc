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
#include "scene/feature_io.h"
#include "triangulation/map_triangulation.h"
#include "util/testing.h"
#include "util/timer.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;

// Per matcher, the queries within (0.25 m, 2 deg) and within (0.5 m, 5 deg).
struct QueryCounts {
  int fine = 0;
  int medium = 0;
};
using CountsPerMatcher = std::map<Matcher, QueryCounts>;

CountsPerMatcher LocalizeWithXFeat(const fs::path& data, const fs::path& weights) {
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

  // Trained as `hscloc train` trains without options: its budget for the map, 5 % held out.
  const TrainedRealMap trained =
      BuildAndTrainRealMap(temp / "model", features, temp / "map", TrainerOptions());
  const Localizer localizer(trained.map, trained.network);

  std::cout << fmt::format(
      "{}: XFeat extracted in {:.1f} s; {} pairs ({} verified), {} verified matches; {} points, "
      "mean track length {:.2f}, mean reprojection error {:.2f} px, triangulated in {:.1f} s; "
      "{} iterations in {:.1f} s\n",
      data.filename().string(), extract_s, triangulated.num_pairs, triangulated.num_verified_pairs,
      triangulated.num_verified_matches, triangulated.num_points3D, triangulated.mean_track_length,
      triangulated.mean_reprojection_error_px, triangulate_s, trained.iterations,
      trained.train_seconds);

  const auto reader = OpenH5Features(features);
  const QuerySet set =
      ReadQuerySet(data / "queries_with_intrinsics.txt", *reader, data / "queries_gt.txt");
  CountsPerMatcher counts;
  for (const Matcher matcher : {Matcher::kNetwork, Matcher::kNearestNeighbor}) {
    for (const QueryPoseError& error : LocalizeAndPrint(localizer, matcher, set).accuracy.errors) {
      counts[matcher].fine += error.position <= 0.25 && error.rotation_deg <= 2.0;
      counts[matcher].medium += error.position <= 0.5 && error.rotation_deg <= 5.0;
    }
  }
  return counts;
}

// The set's queries within (0.25 m, 2 deg) with the network and with the baseline: at least
// these many; and every query within (0.5 m, 5 deg) with both. Skips without the set, XFeat's
// weights or COLMAP.
void ExpectQueries(const std::string& set, int network_fine, int nearest_neighbor_fine) {
  HSCLOC_REQUIRE_REAL_DATA(data, set);
  HSCLOC_REQUIRE_REAL_DATA(weights, "weights/xfeat");
  HSCLOC_REQUIRE_COLMAP(colmap);
  CountsPerMatcher counts = LocalizeWithXFeat(data, weights);
  const auto num_queries =
      static_cast<int>(ReadQueryList(data / "queries_with_intrinsics.txt").size());
  EXPECT_GE(counts[Matcher::kNetwork].fine, network_fine);
  EXPECT_GE(counts[Matcher::kNearestNeighbor].fine, nearest_neighbor_fine);
  for (const Matcher matcher : {Matcher::kNetwork, Matcher::kNearestNeighbor}) {
    EXPECT_EQ(counts[matcher].medium, num_queries) << MatcherName(matcher);
  }
}

// Fountain's two queries come within 2 cm and 0.1 deg (SIFT: 2.5 mm).
TEST(XFeatRealDataTest, FountainQueriesWithinQuarterMetreAndTwoDegrees) {
  ExpectQueries("fountain-P11", 2, 2);
}

// Lund with XFeat (photos seen at 1024 px through 2 x 2 tiles): the nearest-neighbour baseline
// localizes all 5 queries within (0.25 m, 2 deg), at most 0.12 m off whatever the network that
// votes, and so does the network with `hscloc train`'s own budget over training seeds 0 to 3
// (at most 0.15 m off, the final pose pooled over the candidates that agree). Another CPU trains
// another network from the same seed: one placed 20.jpg 0.45 m off with the winner's pose alone,
// so the network is held to 4 of 5 within the bound and all 5 within (0.5 m, 5 deg).
TEST(XFeatRealDataTest, LundQueries) { ExpectQueries("lund", 4, 5); }

}  // namespace
}  // namespace hscloc
