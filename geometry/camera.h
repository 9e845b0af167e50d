// COLMAP camera models: ids, names, parameter layouts, projection and unprojection.
//
// Conventions (COLMAP): the camera looks along +z, x right, y down; pixel coordinates put the
// centre of the top-left pixel at (0.5, 0.5). "Normalized" coordinates are (x/z, y/z) of a point
// in the camera frame, before distortion.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <string>
#include <vector>

#include "util/types.h"

namespace hscloc {

// The ids COLMAP stores in cameras.bin / database.db.
enum class CameraModelId : int {
  kInvalid = -1,
  kSimplePinhole = 0,        // f, cx, cy
  kPinhole = 1,              // fx, fy, cx, cy
  kSimpleRadial = 2,         // f, cx, cy, k
  kRadial = 3,               // f, cx, cy, k1, k2
  kOpenCV = 4,               // fx, fy, cx, cy, k1, k2, p1, p2
  kOpenCVFisheye = 5,        // fx, fy, cx, cy, k1, k2, k3, k4
  kFullOpenCV = 6,           // fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6
  kFOV = 7,                  // fx, fy, cx, cy, omega
  kSimpleRadialFisheye = 8,  // f, cx, cy, k
  kRadialFisheye = 9,        // f, cx, cy, k1, k2
  kThinPrismFisheye = 10,    // fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, sx1, sy1
};

// True for the ids above, kInvalid excluded.
bool IsKnownCameraModelId(int model_id);
// "SIMPLE_RADIAL" etc.; throws std::invalid_argument for an unknown id.
std::string CameraModelName(CameraModelId model_id);
// The id for a COLMAP model name; throws std::invalid_argument naming the unknown name.
CameraModelId CameraModelIdFromName(const std::string& name);
// Number of parameters of a model; throws for an unknown id.
size_t CameraModelNumParams(CameraModelId model_id);

struct Camera {
  camera_t camera_id = kInvalidCameraId;
  CameraModelId model_id = CameraModelId::kInvalid;
  uint64_t width = 0;
  uint64_t height = 0;
  std::vector<double> params;

  // Throws std::invalid_argument naming the camera and the field: unknown model, wrong parameter
  // count, zero size, non-finite parameters, non-positive focal length.
  void Check() const;

  // Builds a camera from a model name and parameters, then Check()s it.
  static Camera FromModelName(camera_t camera_id, const std::string& model_name, uint64_t width,
                              uint64_t height, std::vector<double> params);

  // Mean of the focal lengths (fx, fy or f), in pixels.
  double MeanFocalLength() const;

  // The projection functions below throw std::invalid_argument for an unknown model or a
  // parameter count that does not match it, but do not repeat the rest of Check().

  // Normalized coordinates (x/z, y/z) -> distorted pixel coordinates: u = fx * x_distorted + cx.
  // The fisheye models distort the angle theta = atan(r) from the axis (OPENCV_FISHEYE:
  // theta_d = theta (1 + k1 theta^2 + ... + k4 theta^8)); THIN_PRISM_FISHEYE applies its
  // polynomial to the equidistant coordinates theta (x, y) / r. FOV follows the closed form of
  // Devernay and Faugeras (MVA 2001) for every omega. COLMAP 3.8 swaps in a series below
  // omega = 0.01 whose sign is wrong in this direction; there the two differ by a relative
  // omega^2 (2 r^2 / 3 - 1 / 6).
  Eigen::Vector2d ImgFromCam(const Eigen::Vector2d& normalized) const;
  // Pixel coordinates -> undistorted normalized coordinates (x/z, y/z); inverts ImgFromCam to
  // about 1e-15 (Newton on the radius or angle for the radial models, on both coordinates for the
  // OpenCV and thin-prism models, closed form for FOV). Returns NaN coordinates where the
  // distortion has no inverse: beyond the fold of a strong barrel distortion, or at 90 degrees
  // and more from the axis.
  Eigen::Vector2d CamFromImg(const Eigen::Vector2d& pixel) const;
  // A point in the camera frame (z > 0) -> pixel coordinates.
  Eigen::Vector2d ImgFromPointInCam(const Eigen::Vector3d& point_in_cam) const {
    return ImgFromCam(point_in_cam.hnormalized());
  }
  // True when the pixel lies inside [0, width] x [0, height].
  bool IsInside(const Eigen::Vector2d& pixel) const {
    return pixel.x() >= 0 && pixel.y() >= 0 && pixel.x() <= width && pixel.y() <= height;
  }
};

}  // namespace hscloc
