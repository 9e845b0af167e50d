// The map's scene in dense form: database images and 3D points indexed 0..n-1 (the indices the
// label tree, the visibility lists and the network's image embedding use), with their COLMAP ids
// kept beside them, and every observation with its descriptor.
#pragma once

#include <Eigen/Core>
#include <map>
#include <string>
#include <unordered_map>
#include <vector>

#include "geometry/camera.h"
#include "geometry/rigid3d.h"
#include "scene/features.h"
#include "scene/reconstruction.h"

namespace hscloc {

struct SceneImage {
  image_t image_id = kInvalidImageId;
  std::string name;
  camera_t camera_id = kInvalidCameraId;
  Rigid3d cam_from_world;
};

struct Scene {
  std::map<camera_t, Camera> cameras;
  std::vector<SceneImage> images;       // dense image index -> image
  std::vector<point3D_t> point3D_ids;   // dense point index -> COLMAP id
  std::vector<Eigen::Vector3d> points;  // dense point index -> position in world
  // Observations: one row per (image, keypoint) seeing a point.
  std::vector<uint32_t> observation_image_indices;
  std::vector<uint32_t> observation_point_indices;
  DescriptorMatrix observation_descriptors;

  size_t NumImages() const { return images.size(); }
  size_t NumPoints() const { return points.size(); }
  size_t NumObservations() const { return observation_image_indices.size(); }
  int64_t Dimension() const { return observation_descriptors.cols(); }

  // Dense index of an image id / point id; throws std::invalid_argument when unknown.
  uint32_t ImageIndex(image_t image_id) const;
  uint32_t PointIndex(point3D_t point3D_id) const;

  // Images in image-id order, points in point3D-id order; observations as joined (features of
  // every 2D point with a 3D point). Points without any observation are kept (they are still
  // predicted by nothing but cost nothing). Throws std::invalid_argument naming the observation
  // and the id when an observation refers to an image or point the reconstruction lacks.
  // Observations without descriptors (ObservationIndices) give a scene of indices only, whose
  // Dimension() is 0; the descriptors are moved, never copied.
  static Scene FromReconstruction(const Reconstruction& reconstruction, Observations observations);

 private:
  std::unordered_map<image_t, uint32_t> image_index_of_id_;
  std::unordered_map<point3D_t, uint32_t> point_index_of_id_;
  friend class SceneAccess;

 public:
  // Rebuilds the id -> index lookups after images or point3D_ids were assigned directly; throws
  // when an id appears twice.
  void RebuildIndex();
};

}  // namespace hscloc
