#include "scene/scene.h"

#include <limits>

#include "util/check.h"

namespace hscloc {

uint32_t Scene::ImageIndex(image_t image_id) const {
  const auto found = image_index_of_id_.find(image_id);
  if (found == image_index_of_id_.end()) {
    ThrowInvalidArgument("scene: unknown image id {}", image_id);
  }
  return found->second;
}

uint32_t Scene::PointIndex(point3D_t point3D_id) const {
  const auto found = point_index_of_id_.find(point3D_id);
  if (found == point_index_of_id_.end()) {
    ThrowInvalidArgument("scene: unknown point3D id {}", point3D_id);
  }
  return found->second;
}

void Scene::RebuildIndex() {
  if (images.size() > std::numeric_limits<uint32_t>::max() ||
      point3D_ids.size() > std::numeric_limits<uint32_t>::max()) {
    ThrowInvalidArgument("scene: {} images and {} points do not fit 32-bit indices", images.size(),
                         point3D_ids.size());
  }
  image_index_of_id_.clear();
  image_index_of_id_.reserve(images.size());
  for (size_t i = 0; i < images.size(); ++i) {
    if (!image_index_of_id_.emplace(images[i].image_id, static_cast<uint32_t>(i)).second) {
      ThrowInvalidArgument("scene: image id {} appears twice", images[i].image_id);
    }
  }
  point_index_of_id_.clear();
  point_index_of_id_.reserve(point3D_ids.size());
  for (size_t p = 0; p < point3D_ids.size(); ++p) {
    if (!point_index_of_id_.emplace(point3D_ids[p], static_cast<uint32_t>(p)).second) {
      ThrowInvalidArgument("scene: point3D id {} appears twice", point3D_ids[p]);
    }
  }
}

Scene Scene::FromReconstruction(const Reconstruction& reconstruction, Observations observations) {
  const size_t num_observations = observations.size();
  const bool indices_only = observations.descriptors.size() == 0;
  if (observations.keypoint_indices.size() != num_observations ||
      observations.point3D_ids.size() != num_observations ||
      (!indices_only && static_cast<size_t>(observations.descriptors.rows()) != num_observations)) {
    ThrowInvalidArgument(
        "observations: {} image ids, {} keypoint indices, {} point3D ids and {} descriptors",
        num_observations, observations.keypoint_indices.size(), observations.point3D_ids.size(),
        observations.descriptors.rows());
  }

  Scene scene;
  scene.cameras = reconstruction.cameras;
  // std::map iterates in id order, which is the dense order.
  scene.images.reserve(reconstruction.images.size());
  for (const auto& [image_id, image] : reconstruction.images) {
    scene.images.push_back({image_id, image.name, image.camera_id, image.cam_from_world});
  }
  scene.point3D_ids.reserve(reconstruction.points3D.size());
  scene.points.reserve(reconstruction.points3D.size());
  for (const auto& [point3D_id, point3D] : reconstruction.points3D) {
    scene.point3D_ids.push_back(point3D_id);
    scene.points.push_back(point3D.xyz);
  }
  scene.RebuildIndex();

  scene.observation_image_indices.resize(num_observations);
  scene.observation_point_indices.resize(num_observations);
  for (size_t i = 0; i < num_observations; ++i) {
    const auto image = scene.image_index_of_id_.find(observations.image_ids[i]);
    if (image == scene.image_index_of_id_.end()) {
      ThrowInvalidArgument("observation {}: image id {} is not in the reconstruction", i,
                           observations.image_ids[i]);
    }
    const auto point = scene.point_index_of_id_.find(observations.point3D_ids[i]);
    if (point == scene.point_index_of_id_.end()) {
      ThrowInvalidArgument("observation {}: point3D id {} is not in the reconstruction", i,
                           observations.point3D_ids[i]);
    }
    scene.observation_image_indices[i] = image->second;
    scene.observation_point_indices[i] = point->second;
  }
  scene.observation_descriptors = std::move(observations.descriptors);
  return scene;
}

}  // namespace hscloc
