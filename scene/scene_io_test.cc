#include "scene/scene_io.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <random>
#include <sstream>

namespace hscloc {
namespace {

using ::testing::HasSubstr;

Scene RandomScene(int num_images, int num_points, int num_observations, int dimension) {
  std::mt19937 random(11);
  std::uniform_real_distribution<double> uniform(-50, 50);
  Scene scene;
  Camera camera = Camera::FromModelName(3, "SIMPLE_RADIAL", 1024, 768, {900, 512, 384, 0.01});
  scene.cameras.emplace(camera.camera_id, camera);
  for (int i = 0; i < num_images; ++i) {
    SceneImage image;
    image.image_id = static_cast<image_t>(10 + 3 * i);
    image.name = "db/image " + std::to_string(i) + ".jpg";
    image.camera_id = 3;
    image.cam_from_world = Rigid3d(Eigen::Quaterniond::UnitRandom(),
                                   Eigen::Vector3d(uniform(random), uniform(random), 0));
    scene.images.push_back(image);
  }
  for (int p = 0; p < num_points; ++p) {
    scene.point3D_ids.push_back(static_cast<point3D_t>(1000 + 7 * p));
    scene.points.emplace_back(uniform(random), uniform(random), uniform(random));
  }
  scene.observation_descriptors.resize(num_observations, dimension);
  for (int o = 0; o < num_observations; ++o) {
    scene.observation_image_indices.push_back(random() % num_images);
    scene.observation_point_indices.push_back(random() % num_points);
    for (int d = 0; d < dimension; ++d) {
      scene.observation_descriptors(o, d) = static_cast<float>(random() % 256);
    }
  }
  scene.RebuildIndex();
  return scene;
}

TEST(SceneIo, GeometryRoundTripsExactly) {
  const Scene scene = RandomScene(5, 40, 0, 8);
  std::stringstream stream;
  WriteSceneGeometry(stream, scene);
  const Scene read = ReadSceneGeometry(stream, "scene.bin");
  ASSERT_EQ(read.images.size(), scene.images.size());
  for (size_t i = 0; i < scene.images.size(); ++i) {
    EXPECT_EQ(read.images[i].image_id, scene.images[i].image_id);
    EXPECT_EQ(read.images[i].name, scene.images[i].name);
    EXPECT_EQ(read.images[i].cam_from_world.rotation.coeffs(),
              scene.images[i].cam_from_world.rotation.coeffs());
    EXPECT_EQ(read.images[i].cam_from_world.translation,
              scene.images[i].cam_from_world.translation);
    EXPECT_EQ(read.ImageIndex(scene.images[i].image_id), i);
  }
  EXPECT_EQ(read.point3D_ids, scene.point3D_ids);
  EXPECT_EQ(read.points, scene.points);
  EXPECT_EQ(read.cameras.at(3).params, scene.cameras.at(3).params);
  EXPECT_EQ(read.PointIndex(1007), 1u);
}

TEST(SceneIo, ObservationsRoundTripAtHalfPrecision) {
  const Scene scene = RandomScene(4, 30, 200, 128);
  std::stringstream geometry, observations;
  WriteSceneGeometry(geometry, scene);
  WriteSceneObservations(observations, scene);
  Scene read = ReadSceneGeometry(geometry, "scene.bin");
  ReadSceneObservations(observations, "observations.bin", read);
  EXPECT_EQ(read.observation_image_indices, scene.observation_image_indices);
  EXPECT_EQ(read.observation_point_indices, scene.observation_point_indices);
  // SIFT's integer values are exact in half precision.
  EXPECT_EQ(read.observation_descriptors, scene.observation_descriptors);
}

TEST(SceneIo, ObservationsWrittenInPiecesEqualTheWholeAndCountTheirRows) {
  const Scene scene = RandomScene(4, 30, 5000, 32);  // more rows than one conversion block
  std::stringstream whole;
  WriteSceneObservations(whole, scene);
  Scene indices_only = scene;
  indices_only.observation_descriptors.resize(0, 0);
  std::stringstream pieces;
  SceneObservationsWriter writer(pieces, indices_only, 32);
  for (Eigen::Index begin = 0; begin < 5000; begin += 777) {
    const Eigen::Index rows = std::min<Eigen::Index>(777, 5000 - begin);
    writer.Append(scene.observation_descriptors.middleRows(begin, rows));
  }
  writer.Finish();
  EXPECT_TRUE(pieces.str() == whole.str());

  std::stringstream short_stream;
  SceneObservationsWriter short_writer(short_stream, indices_only, 32);
  short_writer.Append(scene.observation_descriptors.topRows(10));
  EXPECT_THROW(short_writer.Finish(), std::invalid_argument);
  EXPECT_THROW(short_writer.Append(DescriptorMatrix::Zero(1, 16)), std::invalid_argument);
  EXPECT_THROW(short_writer.Append(DescriptorMatrix::Zero(4991, 32)), std::invalid_argument);
}

TEST(SceneIo, TruncationAnywhereIsAnError) {
  const Scene scene = RandomScene(3, 10, 20, 4);
  std::stringstream geometry, observations;
  WriteSceneGeometry(geometry, scene);
  WriteSceneObservations(observations, scene);
  const std::string geometry_bytes = geometry.str();
  for (size_t cut = 0; cut < geometry_bytes.size(); cut += 7) {
    std::stringstream truncated(geometry_bytes.substr(0, cut));
    EXPECT_THROW(ReadSceneGeometry(truncated, "scene.bin"), std::invalid_argument) << cut;
  }
  const std::string observation_bytes = observations.str();
  for (size_t cut = 0; cut < observation_bytes.size(); cut += 11) {
    Scene read = ReadSceneGeometry(*std::make_unique<std::stringstream>(geometry_bytes), "s");
    std::stringstream truncated(observation_bytes.substr(0, cut));
    EXPECT_THROW(ReadSceneObservations(truncated, "observations.bin", read), std::invalid_argument)
        << cut;
  }
}

TEST(SceneIo, OutOfRangeObservationIsNamed) {
  Scene scene = RandomScene(3, 10, 5, 4);
  scene.observation_point_indices[2] = 99;
  std::stringstream geometry, observations;
  WriteSceneGeometry(geometry, scene);
  WriteSceneObservations(observations, scene);
  Scene read = ReadSceneGeometry(geometry, "scene.bin");
  try {
    ReadSceneObservations(observations, "observations.bin", read);
    FAIL() << "expected an error";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("observations.bin: observation 2"));
  }
}

TEST(SceneIo, WrongBlobKindIsRejected) {
  const Scene scene = RandomScene(2, 3, 1, 4);
  std::stringstream observations;
  WriteSceneObservations(observations, scene);
  EXPECT_THROW(ReadSceneGeometry(observations, "scene.bin"), std::invalid_argument);
}

}  // namespace
}  // namespace hscloc
