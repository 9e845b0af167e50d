// The text formats of visual localization benchmarks (Aachen Day-Night, visuallocalization.net):
//   query list   NAME MODEL WIDTH HEIGHT PARAMS...        (COLMAP camera model and parameters)
//   poses        NAME QW QX QY QZ TX TY TZ                (cam_from_world; ground truth and
//                                                          submissions share it)
// Blank lines and lines starting with '#' are skipped.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "geometry/camera.h"
#include "geometry/rigid3d.h"

namespace hscloc {

struct QueryWithIntrinsics {
  std::string name;
  Camera camera;
};

struct NamedPose {
  std::string name;
  Rigid3d cam_from_world;
};

// Throws std::invalid_argument naming the file and line for a malformed line, an unknown camera
// model, a wrong parameter count or a repeated name.
std::vector<QueryWithIntrinsics> ReadQueryList(const std::filesystem::path& path);
// Also rejects non-finite numbers and quaternions far from unit norm; the rotation is normalized.
std::vector<NamedPose> ReadPoses(const std::filesystem::path& path);

// One line each, newline included; numbers keep their full precision.
std::string FormatIntrinsicsLine(const std::string& name, const Camera& camera);
std::string FormatPoseLine(const std::string& name, const Rigid3d& cam_from_world);

// The image name without its directories ("query/day/0001.jpg" -> "0001.jpg"), the name that
// visuallocalization.net submissions use.
std::string ImageBasename(const std::string& name);

}  // namespace hscloc
