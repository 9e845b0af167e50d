// XFeat end to end on the real sets: features extracted from the photos, the map triangulated
// from the set's own poses (hscloc triangulate), built, trained, and the held-out queries localized
// from their XFeat features with the network and with the nearest-neighbour baseline. The SIFT
// path of the same sets (database.db) is localization/localizer_test.cc's RealDataLocalizerTest.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <iostream>
#include <map>
#include <unordered_map>

#include "features/image_extraction.h"
#include "localization/localizer.h"
#include "localization/map_builder.h"
#include "localization/query_runner.h"
#include "model/trainer.h"
#include "scene/colmap_io.h"
#include "scene/feature_io.h"
#include "scene/query_io.h"
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

  MapBuildOptions build_options;
  build_options.show_progress = false;
  build_options.label_tree.show_progress = false;
  BuildMap({temp / "model", features, std::nullopt}, build_options, temp / "map");
  auto map = LocalizationMap::Load(temp / "map", {.load_observations = true});
  step.Restart();
  // As `hscloc train` trains without options: the widths and the budget it chooses for this map,
  // 5 % of the observations held out to keep the best network.
  TrainerOptions train_options;
  train_options.network = DefaultNetworkOptions(map->scene().NumPoints());
  train_options.show_progress = false;
  TrainingResult training = TrainNetwork(map->scene(), map->label_tree(), train_options);
  const double train_s = step.ElapsedSeconds();
  const Localizer localizer(map, std::make_shared<const Network>(std::move(training.network)));

  std::cout << fmt::format(
      "{}: XFeat extracted in {:.1f} s; {} pairs ({} verified), {} verified matches; {} points, "
      "mean track length {:.2f}, mean reprojection error {:.2f} px, triangulated in {:.1f} s; "
      "{} iterations in {:.1f} s\n",
      data.filename().string(), extract_s, triangulated.num_pairs, triangulated.num_verified_pairs,
      triangulated.num_verified_matches, triangulated.num_points3D, triangulated.mean_track_length,
      triangulated.mean_reprojection_error_px, triangulate_s, training.iterations, train_s);

  const auto reader = OpenH5Features(features);
  const std::vector<LocalizationQuery> queries =
      LoadQueries(data / "queries_with_intrinsics.txt", *reader);
  std::unordered_map<std::string, Rigid3d> truth;
  for (const NamedPose& pose : ReadPoses(data / "queries_gt.txt")) {
    truth[pose.name] = pose.cam_from_world;
  }
  FineCounts counts;
  for (const Matcher matcher : {Matcher::kNetwork, Matcher::kNearestNeighbor}) {
    LocalizerOptions options;
    options.matcher = matcher;
    for (const LocalizationQuery& query : queries) {
      const PoseResult result = localizer.Localize(query, options);
      const Rigid3d& expected = truth.at(query.name);
      const double position_m =
          result.success ? PositionError(result.cam_from_world, expected) : INFINITY;
      const double rotation_deg =
          result.success ? RotationErrorDeg(result.cam_from_world, expected) : INFINITY;
      std::cout << fmt::format(
          "  {:<4} {:<9} position error {:8.4f}  rotation error {:7.3f} deg  "
          "inliers {:4}\n",
          MatcherName(matcher), query.name, position_m, rotation_deg, result.num_inliers);
      counts[matcher] += position_m <= 0.25 && rotation_deg <= 2.0;
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
