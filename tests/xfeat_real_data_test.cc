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

// Per matcher, the queries within (0.25 m, 2 deg).
using FineCounts = std::map<Matcher, int>;

FineCounts LocalizeWithXFeat(const fs::path& data, const fs::path& weights) {
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
  FineCounts counts;
  for (const Matcher matcher : {Matcher::kNetwork, Matcher::kNearestNeighbor}) {
    for (const QueryPoseError& error : LocalizeAndPrint(localizer, matcher, set).accuracy.errors) {
      counts[matcher] += error.position <= 0.25 && error.rotation_deg <= 2.0;
    }
  }
  return counts;
}

// The set's queries within (0.25 m, 2 deg) with the network and with the baseline: at least
// these many. Skips without the set, XFeat's weights or COLMAP.
void ExpectFineQueries(const std::string& set, int network, int nearest_neighbor) {
  HSCLOC_REQUIRE_REAL_DATA(data, set);
  HSCLOC_REQUIRE_REAL_DATA(weights, "weights/xfeat");
  HSCLOC_REQUIRE_COLMAP(colmap);
  FineCounts counts = LocalizeWithXFeat(data, weights);
  EXPECT_GE(counts[Matcher::kNetwork], network);
  EXPECT_GE(counts[Matcher::kNearestNeighbor], nearest_neighbor);
}

// Fountain's two queries come within 2 cm and 0.1 deg (SIFT: 2.5 mm).
TEST(XFeatRealDataTest, FountainQueriesWithinQuarterMetreAndTwoDegrees) {
  ExpectFineQueries("fountain-P11", 2, 2);
}

// Lund with XFeat (photos seen at 1024 px through 2 x 2 tiles): the nearest-neighbour baseline
// localizes all 5 queries within (0.25 m, 2 deg), at most 0.07 m off, and so does the network
// with `hscloc train`'s own budget: over training seeds 0 to 3 at most 0.17 m off, with rival
// keypoints re-chosen by the pose (docs/decisions.md). At 640 px in one pass the network localized
// 2 to 4 and the baseline 4.
TEST(XFeatRealDataTest, LundQueries) { ExpectFineQueries("lund", 5, 5); }

}  // namespace
}  // namespace hscloc
