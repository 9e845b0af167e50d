#include "scene/query_io.h"

#include <fmt/format.h>

#include <cmath>
#include <fstream>
#include <sstream>
#include <unordered_set>

#include "util/check.h"

namespace hscloc {
namespace {

// Calls `parse_line(fields, where)` for every line that holds data.
template <typename ParseLine>
void ForEachDataLine(const std::filesystem::path& path, ParseLine parse_line) {
  std::ifstream file(path);
  if (!file) ThrowInvalidArgument("cannot read {}", path.string());
  std::string line;
  for (int line_number = 1; std::getline(file, line); ++line_number) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    const size_t first = line.find_first_not_of(" \t");
    if (first == std::string::npos || line[first] == '#') continue;
    std::istringstream fields(line);
    parse_line(fields, fmt::format("{}:{}", path.string(), line_number));
  }
}

void CheckUnique(std::unordered_set<std::string>& names, const std::string& name,
                 const std::string& where) {
  if (!names.insert(name).second) ThrowInvalidArgument("{}: '{}' appears twice", where, name);
}

}  // namespace

std::vector<QueryWithIntrinsics> ReadQueryList(const std::filesystem::path& path) {
  std::vector<QueryWithIntrinsics> queries;
  std::unordered_set<std::string> names;
  ForEachDataLine(path, [&](std::istringstream& fields, const std::string& where) {
    std::string name;
    std::string model;
    uint64_t width = 0;
    uint64_t height = 0;
    if (!(fields >> name >> model >> width >> height)) {
      ThrowInvalidArgument("{}: expected NAME MODEL WIDTH HEIGHT PARAMS...", where);
    }
    std::vector<double> params;
    for (std::string token; fields >> token;) {
      try {
        size_t used = 0;
        params.push_back(std::stod(token, &used));
        if (used != token.size()) throw std::invalid_argument(token);
      } catch (const std::exception&) {
        ThrowInvalidArgument("{}: camera parameter '{}' is not a number", where, token);
      }
    }
    CheckUnique(names, name, where);
    try {
      queries.push_back({name, Camera::FromModelName(0, model, width, height, params)});
    } catch (const std::invalid_argument& error) {
      ThrowInvalidArgument("{}: {}", where, error.what());
    }
  });
  return queries;
}

std::vector<NamedPose> ReadPoses(const std::filesystem::path& path) {
  std::vector<NamedPose> poses;
  std::unordered_set<std::string> names;
  ForEachDataLine(path, [&](std::istringstream& fields, const std::string& where) {
    std::string name;
    double v[7];
    if (!(fields >> name >> v[0] >> v[1] >> v[2] >> v[3] >> v[4] >> v[5] >> v[6])) {
      ThrowInvalidArgument("{}: expected NAME QW QX QY QZ TX TY TZ", where);
    }
    std::string extra;
    if (fields >> extra) ThrowInvalidArgument("{}: unexpected '{}' after the pose", where, extra);
    for (const double value : v) {
      if (!std::isfinite(value)) ThrowInvalidArgument("{}: non-finite number in the pose", where);
    }
    Eigen::Quaterniond rotation(v[0], v[1], v[2], v[3]);
    if (std::abs(rotation.norm() - 1) > 1e-3) {
      ThrowInvalidArgument("{}: quaternion of norm {} (expected a unit quaternion)", where,
                           rotation.norm());
    }
    CheckUnique(names, name, where);
    poses.push_back({name, Rigid3d(rotation.normalized(), Eigen::Vector3d(v[4], v[5], v[6]))});
  });
  return poses;
}

std::string FormatIntrinsicsLine(const std::string& name, const Camera& camera) {
  return fmt::format("{} {} {} {} {}\n", name, CameraModelName(camera.model_id), camera.width,
                     camera.height, fmt::join(camera.params, " "));
}

std::string FormatPoseLine(const std::string& name, const Rigid3d& cam_from_world) {
  const Eigen::Quaterniond& q = cam_from_world.rotation;
  const Eigen::Vector3d& t = cam_from_world.translation;
  return fmt::format("{} {} {} {} {} {} {} {}\n", name, q.w(), q.x(), q.y(), q.z(), t.x(), t.y(),
                     t.z());
}

std::string ImageBasename(const std::string& name) {
  const size_t slash = name.find_last_of('/');
  return slash == std::string::npos ? name : name.substr(slash + 1);
}

}  // namespace hscloc
