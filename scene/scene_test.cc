#include "scene/scene.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;

// Three images and three points, inserted with ids out of order; every image sees two points.
Reconstruction MakeReconstruction() {
  Reconstruction reconstruction;
  reconstruction.cameras[2] = Camera::FromModelName(2, "SIMPLE_PINHOLE", 640, 480, {500, 320, 240});
  reconstruction.cameras[1] = Camera::FromModelName(1, "PINHOLE", 800, 600, {700, 710, 400, 300});
  const std::vector<std::pair<image_t, camera_t>> images = {{12, 1}, {3, 2}, {7, 1}};
  for (const auto& [image_id, camera_id] : images) {
    Image image;
    image.image_id = image_id;
    image.name = "db/" + std::to_string(image_id) + ".jpg";
    image.camera_id = camera_id;
    image.cam_from_world.translation = Eigen::Vector3d(image_id, 0, 0);
    reconstruction.images[image_id] = image;
  }
  const std::vector<point3D_t> point_ids = {100, 5, 42};
  for (const point3D_t point3D_id : point_ids) {
    reconstruction.points3D[point3D_id].xyz = Eigen::Vector3d(point3D_id, 1, 2);
  }
  return reconstruction;
}

Observations MakeObservations(const std::vector<std::pair<image_t, point3D_t>>& rows) {
  Observations observations;
  observations.descriptors.resize(static_cast<Eigen::Index>(rows.size()), 4);
  for (size_t i = 0; i < rows.size(); ++i) {
    observations.image_ids.push_back(rows[i].first);
    observations.keypoint_indices.push_back(static_cast<point2D_t>(i));
    observations.point3D_ids.push_back(rows[i].second);
    observations.descriptors.row(static_cast<Eigen::Index>(i)).setConstant(static_cast<float>(i));
  }
  return observations;
}

TEST(Scene, DenseOrderFollowsTheIds) {
  const Observations observations = MakeObservations({{12, 42}, {3, 100}, {7, 5}, {3, 42}});
  const Scene scene = Scene::FromReconstruction(MakeReconstruction(), observations);

  ASSERT_EQ(scene.NumImages(), 3u);
  EXPECT_EQ(scene.images[0].image_id, 3u);
  EXPECT_EQ(scene.images[1].image_id, 7u);
  EXPECT_EQ(scene.images[2].image_id, 12u);
  EXPECT_EQ(scene.images[1].name, "db/7.jpg");
  EXPECT_EQ(scene.images[1].camera_id, 1u);
  EXPECT_EQ(scene.images[0].camera_id, 2u);
  EXPECT_EQ(scene.images[2].cam_from_world.translation.x(), 12.0);
  EXPECT_EQ(scene.cameras.size(), 2u);
  EXPECT_EQ(scene.cameras.at(2).width, 640u);

  EXPECT_THAT(scene.point3D_ids, ElementsAre(5, 42, 100));
  ASSERT_EQ(scene.NumPoints(), 3u);
  EXPECT_EQ(scene.points[0].x(), 5.0);
  EXPECT_EQ(scene.points[2].x(), 100.0);

  ASSERT_EQ(scene.NumObservations(), 4u);
  EXPECT_THAT(scene.observation_image_indices, ElementsAre(2, 0, 1, 0));
  EXPECT_THAT(scene.observation_point_indices, ElementsAre(1, 2, 0, 1));
  EXPECT_EQ(scene.Dimension(), 4);
  EXPECT_TRUE(scene.observation_descriptors.isApprox(observations.descriptors));
}

TEST(Scene, IndexLookups) {
  const Scene scene = Scene::FromReconstruction(MakeReconstruction(), MakeObservations({}));
  EXPECT_EQ(scene.ImageIndex(3), 0u);
  EXPECT_EQ(scene.ImageIndex(12), 2u);
  EXPECT_EQ(scene.PointIndex(5), 0u);
  EXPECT_EQ(scene.PointIndex(100), 2u);
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { scene.ImageIndex(4); }),
              HasSubstr("image id 4"));
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { scene.PointIndex(43); }),
              HasSubstr("point3D id 43"));
  // Points without observations are kept.
  EXPECT_EQ(scene.NumPoints(), 3u);
  EXPECT_EQ(scene.NumObservations(), 0u);
}

TEST(Scene, ObservationsOfUnknownIdsThrowNamingTheId) {
  const Reconstruction reconstruction = MakeReconstruction();
  EXPECT_THAT(testing::InvalidArgumentMessage([&] {
                Scene::FromReconstruction(reconstruction, MakeObservations({{3, 5}, {99, 5}}));
              }),
              HasSubstr("observation 1: image id 99"));
  EXPECT_THAT(testing::InvalidArgumentMessage([&] {
                Scene::FromReconstruction(reconstruction, MakeObservations({{3, 5}, {7, 77}}));
              }),
              HasSubstr("observation 1: point3D id 77"));
  Observations ragged = MakeObservations({{3, 5}, {7, 42}});
  ragged.point3D_ids.pop_back();
  EXPECT_THAT(
      testing::InvalidArgumentMessage([&] { Scene::FromReconstruction(reconstruction, ragged); }),
      HasSubstr("1 point3D ids"));
}

TEST(Scene, RebuildIndexAfterDirectAssignment) {
  Scene scene;
  scene.images.resize(2);
  scene.images[0].image_id = 20;
  scene.images[1].image_id = 10;
  scene.point3D_ids = {8, 9, 1};
  scene.points.resize(3, Eigen::Vector3d::Zero());
  EXPECT_THROW(scene.ImageIndex(20), std::invalid_argument);
  scene.RebuildIndex();
  EXPECT_EQ(scene.ImageIndex(20), 0u);
  EXPECT_EQ(scene.ImageIndex(10), 1u);
  EXPECT_EQ(scene.PointIndex(1), 2u);

  scene.point3D_ids = {8, 9, 8};
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { scene.RebuildIndex(); }),
              HasSubstr("point3D id 8 appears twice"));
}

}  // namespace
}  // namespace hscloc
