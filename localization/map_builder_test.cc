#include "localization/map_builder.h"

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <fstream>

#include "localization/localization_map.h"
#include "map/map_bundle.h"
#include "map/point_descriptors.h"
#include "scene/colmap_io.h"
#include "scene/feature_io.h"
#include "synthetic/synthetic_city.h"
#include "synthetic/synthetic_city_writer.h"
#include "util/testing.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

MapBuildOptions QuietOptions() {
  MapBuildOptions options;
  options.show_progress = false;
  options.label_tree.show_progress = false;
  return options;
}

// A tiny synthetic city on disk, written once for the whole suite.
class MapBuilderTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    city_dir_ = new testing::TempDir();
    SyntheticCityWriteOptions write_options;
    write_options.show_progress = false;
    WriteSyntheticCity(SyntheticCity(SyntheticCityOptions::Preset("tiny")),
                       city_dir_->path() / "city", write_options);
  }
  static void TearDownTestSuite() { delete city_dir_; }
  static fs::path CityDir() { return city_dir_->path() / "city"; }
  static MapBuildInputs CityInputs() {
    return {CityDir() / "map", CityDir() / "features.h5", std::nullopt};
  }

  testing::TempDir temp_;

 private:
  static testing::TempDir* city_dir_;
};
testing::TempDir* MapBuilderTest::city_dir_ = nullptr;

void FlipByte(const fs::path& path, size_t offset) {
  std::fstream file(path, std::ios::in | std::ios::out | std::ios::binary);
  file.seekg(static_cast<std::streamoff>(offset));
  char byte;
  file.read(&byte, 1);
  byte = static_cast<char>(byte ^ 0x5a);
  file.seekp(static_cast<std::streamoff>(offset));
  file.write(&byte, 1);
}

TEST_F(MapBuilderTest, BuildsALoadableConsistentMap) {
  const MapBuildSummary summary = BuildMap(CityInputs(), QuietOptions(), temp_ / "map");
  const Reconstruction reconstruction = ReadColmapModel(CityDir() / "map");
  EXPECT_EQ(summary.num_images, reconstruction.images.size());
  EXPECT_EQ(summary.num_points, reconstruction.points3D.size());
  EXPECT_EQ(summary.num_observations, reconstruction.NumObservations());
  EXPECT_GT(summary.bundle_bytes, 0u);

  const auto map = LocalizationMap::Load(temp_ / "map", {.load_observations = true});
  const Scene& scene = map->scene();
  EXPECT_EQ(scene.NumPoints(), reconstruction.points3D.size());
  EXPECT_EQ(map->descriptor_dim(), 64);
  EXPECT_EQ(map->metadata()["label_tree"]["levels"], 4);
  ASSERT_TRUE(map->vlad().has_value());
  EXPECT_EQ(map->network(), nullptr);  // not trained yet

  // Every point decodes from its label path; every observation is in the visibility lists.
  const LabelTree& tree = map->label_tree();
  for (uint32_t p = 0; p < scene.NumPoints(); ++p) {
    ASSERT_EQ(tree.PointOfLabels(tree.LabelsOfPoint(p)), p);
  }
  for (size_t o = 0; o < scene.NumObservations(); ++o) {
    ASSERT_TRUE(map->visibility().IsVisible(scene.observation_image_indices[o],
                                            scene.observation_point_indices[o]));
  }
  // Each point's descriptor is the unit mean of its observations' unit descriptors.
  const PointDescriptors& point_descriptors = map->point_descriptors();
  ASSERT_EQ(point_descriptors.NumPoints(), scene.NumPoints());
  DescriptorMatrix means = DescriptorMatrix::Zero(scene.NumPoints(), scene.Dimension());
  for (size_t o = 0; o < scene.NumObservations(); ++o) {
    means.row(scene.observation_point_indices[o]) +=
        scene.observation_descriptors.row(static_cast<Eigen::Index>(o)).normalized();
  }
  std::vector<uint32_t> points(scene.NumPoints());
  for (uint32_t p = 0; p < scene.NumPoints(); ++p) points[p] = p;
  const DescriptorMatrix rows = point_descriptors.UnitRows(points.data(), points.size());
  for (uint32_t p = 0; p < scene.NumPoints(); ++p) {
    ASSERT_GT(rows.row(p).dot(means.row(p).normalized()), 0.999f) << "point " << p;
  }
  // The stored global descriptors are the VLAD of each image: an image retrieves itself first.
  const auto features = OpenFeatureReader(CityDir() / "features.h5");
  for (uint32_t i = 0; i < scene.NumImages(); i += 17) {
    const Eigen::VectorXf global =
        map->vlad()->Encode(features->Read(scene.images[i].name).descriptors);
    EXPECT_TRUE(global.isApprox(map->global_descriptors().row(i).transpose(), 1e-5f));
    EXPECT_EQ(map->global_index().Search(global, 1).at(0).image_index, i);
  }
}

TEST_F(MapBuilderTest, CorruptOrMissingPartsAreNamed) {
  BuildMap(CityInputs(), QuietOptions(), temp_ / "map");
  fs::copy(temp_ / "map", temp_ / "flipped", fs::copy_options::recursive);
  FlipByte(temp_ / "flipped" / "label_tree.bin", 40);
  try {
    LocalizationMap::Load(temp_ / "flipped");
    FAIL() << "a flipped byte was not detected";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("label_tree.bin"));
  }
  fs::copy(temp_ / "map", temp_ / "missing", fs::copy_options::recursive);
  fs::remove(temp_ / "missing" / "visibility.bin");
  try {
    LocalizationMap::Load(temp_ / "missing");
    FAIL() << "a missing file was not detected";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("visibility.bin"));
  }
}

TEST_F(MapBuilderTest, PointDescriptorsOfAnotherMapAreRejected) {
  BuildMap(CityInputs(), QuietOptions(), temp_ / "map");
  const size_t num_points = LocalizationMap::Load(temp_ / "map")->scene().NumPoints();
  {
    PointDescriptorAccumulator fewer(num_points - 1);
    const uint32_t point = 0;
    fewer.Add(DescriptorMatrix::Ones(1, 64), &point);
    const PointDescriptors other = fewer.Finish();
    MapBundleWriter writer = MapBundleWriter::Update(temp_ / "map");
    writer.AddBlob(map_blobs::kPointDescriptors, [&](std::ostream& s) { other.Write(s); });
    writer.Commit();
  }
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { LocalizationMap::Load(temp_ / "map"); }),
              HasSubstr(fmt::format("{} point descriptors of dimension 64, scene of {} points",
                                    num_points - 1, num_points)));
  // A map loaded without them serves as before.
  const auto map = LocalizationMap::Load(temp_ / "map", {.load_point_descriptors = false});
  EXPECT_TRUE(map->point_descriptors().empty());
}

TEST_F(MapBuilderTest, AFailedBuildKeepsTheOldMap) {
  BuildMap(CityInputs(), QuietOptions(), temp_ / "map");
  MapBuildInputs broken = CityInputs();
  broken.features = temp_ / "no_such_features.h5";
  EXPECT_THROW(BuildMap(broken, QuietOptions(), temp_ / "map"), std::invalid_argument);
  EXPECT_NO_THROW(LocalizationMap::Load(temp_ / "map"));
}

TEST_F(MapBuilderTest, UsesExternalGlobalDescriptors) {
  const Reconstruction reconstruction = ReadColmapModel(CityDir() / "map");
  std::unordered_map<std::string, Eigen::VectorXf> globals;
  for (const auto& [image_id, image] : reconstruction.images) {
    // A descriptor that identifies the image: its id on a few axes.
    Eigen::VectorXf descriptor = Eigen::VectorXf::Constant(32, 0.01f);
    descriptor[image_id % 32] += 1.0f;
    descriptor[(image_id / 32) % 32] += 0.5f;
    globals[image.name] = descriptor;
  }
  WriteH5GlobalDescriptors(temp_ / "globals.h5", globals, H5FloatPrecision::kFloat32);
  MapBuildInputs inputs = CityInputs();
  inputs.global_features = temp_ / "globals.h5";
  const MapBuildSummary summary = BuildMap(inputs, QuietOptions(), temp_ / "map");
  EXPECT_EQ(summary.global_descriptor_dim, 32);
  const auto map = LocalizationMap::Load(temp_ / "map");
  EXPECT_FALSE(map->vlad().has_value());
  EXPECT_EQ(map->metadata()["retrieval"]["global_descriptor"], "external");

  globals.erase(globals.begin());
  WriteH5GlobalDescriptors(temp_ / "partial.h5", globals, H5FloatPrecision::kFloat32);
  inputs.global_features = temp_ / "partial.h5";
  try {
    BuildMap(inputs, QuietOptions(), temp_ / "map2");
    FAIL() << "a database image without a global descriptor was accepted";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("no descriptor for database image"));
  }
}

class RealDataMapTest : public ::testing::TestWithParam<std::string> {};

TEST_P(RealDataMapTest, BuildsFromColmapDatabase) {
  HSCLOC_REQUIRE_REAL_DATA(data, GetParam());
  testing::TempDir temp;
  const MapBuildSummary summary =
      BuildMap({data / "map", data / "database.db", std::nullopt}, QuietOptions(), temp / "map");
  const Reconstruction reconstruction = ReadColmapModel(data / "map");
  EXPECT_EQ(summary.num_points, reconstruction.points3D.size());
  EXPECT_EQ(summary.num_observations, reconstruction.NumObservations());
  EXPECT_EQ(summary.descriptor_dim, 128);
  const auto map = LocalizationMap::Load(temp / "map");
  // With fewer images than the whitening dimension, PCA keeps num_images - 1 components.
  EXPECT_EQ(map->global_index().dimension(), static_cast<int>(reconstruction.images.size()) - 1);
  for (uint32_t p = 0; p < map->scene().NumPoints(); ++p) {
    ASSERT_EQ(map->label_tree().PointOfLabels(map->label_tree().LabelsOfPoint(p)), p);
  }
}

INSTANTIATE_TEST_SUITE_P(RealData, RealDataMapTest, ::testing::Values("fountain-P11", "lund"),
                         [](const auto& info) {
                           std::string name = info.param;
                           std::replace(name.begin(), name.end(), '-', '_');
                           return name;
                         });

}  // namespace
}  // namespace hscloc
