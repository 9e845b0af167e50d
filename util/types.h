// Identifier types, as COLMAP defines them (its files store them with these widths).
#pragma once

#include <cstdint>
#include <limits>

namespace hscloc {

using camera_t = uint32_t;
using image_t = uint32_t;
using point2D_t = uint32_t;
using point3D_t = uint64_t;

inline constexpr camera_t kInvalidCameraId = std::numeric_limits<camera_t>::max();
inline constexpr image_t kInvalidImageId = std::numeric_limits<image_t>::max();
inline constexpr point2D_t kInvalidPoint2DIdx = std::numeric_limits<point2D_t>::max();
// COLMAP writes -1 as the point3D id of a 2D point without a 3D point (binary: as uint64).
inline constexpr point3D_t kInvalidPoint3DId = std::numeric_limits<point3D_t>::max();

}  // namespace hscloc
