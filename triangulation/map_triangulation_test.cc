#include "triangulation/map_triangulation.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <fstream>
#include <iterator>

#include "scene/colmap_io.h"
#include "scene/feature_io.h"
#include "util/testing.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

MapTriangulationOptions QuietOptions(const std::string& colmap) {
  MapTriangulationOptions options;
  options.colmap.colmap_executable = colmap;
  options.show_progress = false;
  return options;
}

// Fountain's map again from its own SIFT features (database.db) and poses: the triangulated model
// keeps the poses, indexes the database's keypoints (the join build-map makes accepts it) and
// holds about as many points as the shipped map, which COLMAP triangulated from exhaustive
// matches.
TEST(MapTriangulation, FountainFromItsOwnFeaturesAndPoses) {
  HSCLOC_REQUIRE_REAL_DATA(data, "fountain-P11");
  HSCLOC_REQUIRE_COLMAP(colmap);
  testing::TempDir temp;
  const MapTriangulationSummary summary = TriangulateMap(
      {data / "map", data / "database.db", data / "images"}, QuietOptions(colmap), temp / "model");
  const Reconstruction shipped = ReadColmapModel(data / "map");
  const Reconstruction triangulated = ReadColmapModel(temp / "model");
  EXPECT_EQ(summary.num_images, 9);
  EXPECT_EQ(summary.num_pairs, 36);  // every pair of 9 images shares points
  EXPECT_GE(summary.num_verified_pairs, 30);
  EXPECT_EQ(summary.num_registered_images, 9);
  EXPECT_EQ(summary.num_points3D, static_cast<int64_t>(triangulated.points3D.size()));
  EXPECT_GT(summary.num_points3D, static_cast<int64_t>(0.8 * shipped.points3D.size()));
  EXPECT_GT(summary.mean_track_length, 2.5);
  EXPECT_LT(summary.mean_reprojection_error_px, 1.5);
  for (const auto& [image_id, image] : shipped.images) {
    SCOPED_TRACE(image.name);
    const Image& ours = triangulated.images.at(image_id);
    EXPECT_EQ(ours.name, image.name);
    EXPECT_LT(PositionError(ours.cam_from_world, image.cam_from_world), 1e-9);
  }
  const auto features = OpenFeatureReader(data / "database.db");
  EXPECT_EQ(JoinObservations(triangulated, *features).size(), triangulated.NumObservations());
  EXPECT_TRUE(fs::exists(temp / "model" / MapTriangulationFiles::kColmapLog));
  EXPECT_TRUE(fs::exists(temp / "model" / MapTriangulationFiles::kDatabase));
}

// Matching in chunks of at most 3 images' descriptors gives the database, match for match, that
// matching with every image's descriptors at once gives; each chunk reads what it lacks.
TEST(MapTriangulation, MatchesDoNotDependOnHowManyImagesAreHeld) {
  HSCLOC_REQUIRE_REAL_DATA(data, "fountain-P11");
  HSCLOC_REQUIRE_COLMAP(colmap);
  testing::TempDir temp;
  const MapTriangulationInputs inputs = {data / "map", data / "database.db", {}};
  const MapTriangulationSummary all_at_once =
      TriangulateMap(inputs, QuietOptions(colmap), temp / "all");
  MapTriangulationOptions chunked_options = QuietOptions(colmap);
  chunked_options.max_images_in_memory = 3;
  const MapTriangulationSummary chunked = TriangulateMap(inputs, chunked_options, temp / "chunked");
  EXPECT_EQ(all_at_once.num_matching_chunks, 1);
  EXPECT_EQ(all_at_once.num_descriptor_reads, 0) << "kept from the first read";
  // 36 pairs of 9 images, at most 3 images and so at most 3 pairs per chunk.
  EXPECT_GE(chunked.num_matching_chunks, 12);
  EXPECT_GT(chunked.num_descriptor_reads, 9);
  EXPECT_EQ(chunked.num_matches, all_at_once.num_matches);
  EXPECT_EQ(chunked.num_verified_pairs, all_at_once.num_verified_pairs);
  EXPECT_EQ(chunked.num_verified_matches, all_at_once.num_verified_matches);
  const auto read_file = [](const fs::path& path) {
    std::ifstream stream(path, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(stream), std::istreambuf_iterator<char>());
  };
  EXPECT_EQ(read_file(temp / "chunked" / "points3D.bin"), read_file(temp / "all" / "points3D.bin"));
}

TEST(MapTriangulation, BadInputsAreNamed) {
  HSCLOC_REQUIRE_REAL_DATA(data, "fountain-P11");
  testing::TempDir temp;
  const MapTriangulationOptions options = QuietOptions("sh");  // never reached
  EXPECT_THAT(testing::InvalidArgumentMessage([&] {
                TriangulateMap({temp / "nowhere", data / "database.db", {}}, options, temp / "a");
              }),
              HasSubstr("nowhere"));

  // Features of two of the nine images; then all nine at twice their size; then all nine from
  // photos of half the size (the keypoints still inside the cameras: only the recorded size says).
  const auto database = OpenFeatureReader(data / "database.db");
  const Reconstruction model = ReadColmapModel(data / "map");
  {
    H5FeatureWriter partial(temp / "partial.h5", H5FloatPrecision::kFloat32);
    H5FeatureWriter doubled(temp / "doubled.h5", H5FloatPrecision::kFloat32);
    H5FeatureWriter halved(temp / "halved.h5", H5FloatPrecision::kFloat32);
    int written = 0;
    for (const auto& [image_id, image] : model.images) {
      ImageFeatures features = database->Read(image.name);
      if (written++ < 2) partial.Write(image.name, features, 1536, 1024);
      ImageFeatures scaled = features;
      scaled.keypoints *= 2;
      doubled.Write(image.name, scaled, 3072, 2048);
      scaled.keypoints = features.keypoints / 2;
      halved.Write(image.name, scaled, 768, 512);
    }
    partial.Close();
    doubled.Close();
    halved.Close();
  }
  EXPECT_THAT(testing::InvalidArgumentMessage([&] {
                TriangulateMap({data / "map", temp / "partial.h5", {}}, options, temp / "b");
              }),
              HasSubstr("partial.h5 has no features for 7 of the model's 9 images"));
  EXPECT_THAT(testing::InvalidArgumentMessage([&] {
                TriangulateMap({data / "map", temp / "doubled.h5", {}}, options, temp / "c");
              }),
              ::testing::AllOf(HasSubstr("a photo of 3072 x 2048 pixels"),
                               HasSubstr("from photos of the camera's size")));
  EXPECT_THAT(
      testing::InvalidArgumentMessage([&] {
        TriangulateMap({data / "map", temp / "halved.h5", {}}, options, temp / "e");
      }),
      ::testing::AllOf(HasSubstr("a photo of 768 x 512 pixels"), HasSubstr("is 1536 x 1024"),
                       HasSubstr("from photos of the camera's size")));
  EXPECT_THAT(testing::InvalidArgumentMessage([&] {
                TriangulateMap({data / "map", data / "database.db", {}},
                               QuietOptions("/nowhere/colmap"), temp / "d");
              }),
              HasSubstr("'/nowhere/colmap' was not found"));
}

}  // namespace
}  // namespace hscloc
