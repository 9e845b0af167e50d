// A COLMAP reconstruction held in memory: cameras, registered images with their 2D points, and
// 3D points with their tracks. Ids are COLMAP's and are kept as read.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "geometry/camera.h"
#include "geometry/rigid3d.h"
#include "util/types.h"

namespace hscloc {

struct Point2D {
  Eigen::Vector2d xy = Eigen::Vector2d::Zero();  // pixels, COLMAP convention
  point3D_t point3D_id = kInvalidPoint3DId;
  bool HasPoint3D() const { return point3D_id != kInvalidPoint3DId; }
};

struct Image {
  image_t image_id = kInvalidImageId;
  std::string name;
  camera_t camera_id = kInvalidCameraId;
  Rigid3d cam_from_world;
  // In keypoint order: POINT2D_IDX of a track is the index here, and, for models built from a
  // COLMAP database, the keypoint row of the image in that database.
  std::vector<Point2D> points2D;
};

struct TrackElement {
  image_t image_id = kInvalidImageId;
  point2D_t point2D_idx = kInvalidPoint2DIdx;
};

struct Point3D {
  Eigen::Vector3d xyz = Eigen::Vector3d::Zero();
  Eigen::Matrix<uint8_t, 3, 1> color = Eigen::Matrix<uint8_t, 3, 1>::Zero();
  double error = -1.0;  // mean reprojection error in pixels; -1 when unknown
  std::vector<TrackElement> track;
};

struct Reconstruction {
  std::map<camera_t, Camera> cameras;
  std::map<image_t, Image> images;
  std::map<point3D_t, Point3D> points3D;

  // Throws std::invalid_argument naming the first inconsistency: an image whose camera is missing,
  // a track element naming a missing image or a 2D point index out of range, a 2D point and a
  // track that disagree, an invalid camera.
  void Check() const;

  size_t NumObservations() const;
};

}  // namespace hscloc
