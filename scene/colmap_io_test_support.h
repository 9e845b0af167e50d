// Random reconstructions and comparisons shared by the COLMAP model I/O tests.
#pragma once

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <numeric>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "scene/colmap_io.h"

namespace hscloc::colmap_io_testing {

namespace fs = std::filesystem;

inline Camera MakeCamera(camera_t camera_id, CameraModelId model_id, std::mt19937& random) {
  std::uniform_real_distribution<double> focal(400, 2000);
  std::uniform_real_distribution<double> distortion(-0.05, 0.05);
  Camera camera;
  camera.camera_id = camera_id;
  camera.model_id = model_id;
  camera.width = 640 + random() % 1400;
  camera.height = 480 + random() % 1000;
  const double cx = camera.width / 2.0 + distortion(random);
  const double cy = camera.height / 2.0 + distortion(random);
  const bool single_focal = model_id == CameraModelId::kSimplePinhole ||
                            model_id == CameraModelId::kSimpleRadial ||
                            model_id == CameraModelId::kRadial;
  camera.params = single_focal ? std::vector<double>{focal(random), cx, cy}
                               : std::vector<double>{focal(random), focal(random), cx, cy};
  while (camera.params.size() < CameraModelNumParams(model_id)) {
    camera.params.push_back(distortion(random));
  }
  return camera;
}

// Cameras of several models, images with and without 2D points, points with consistent tracks;
// ids sparse and, for points, above 2^32 as COLMAP's uint64 allows.
inline Reconstruction RandomReconstruction(uint32_t seed) {
  std::mt19937 random(seed);
  std::uniform_real_distribution<double> unit(0, 1);
  std::normal_distribution<double> normal;
  Reconstruction reconstruction;
  camera_t camera_id = 0;
  for (const CameraModelId model_id :
       {CameraModelId::kSimplePinhole, CameraModelId::kPinhole, CameraModelId::kSimpleRadial,
        CameraModelId::kRadial, CameraModelId::kOpenCV, CameraModelId::kFullOpenCV}) {
    camera_id += 1 + random() % 5;
    reconstruction.cameras[camera_id] = MakeCamera(camera_id, model_id, random);
  }
  std::vector<std::vector<point2D_t>> free_points2D;
  image_t image_id = 0;
  for (int i = 0; i < 9; ++i) {
    Image image;
    image.image_id = image_id += 1 + random() % 100;
    image.name = fmt::format("seq{}/frame_{:04d}.jpg", i % 2, image.image_id);
    auto camera = reconstruction.cameras.begin();
    std::advance(camera, random() % reconstruction.cameras.size());
    image.camera_id = camera->first;
    image.cam_from_world.rotation =
        Eigen::Quaterniond(normal(random), normal(random), normal(random), normal(random))
            .normalized();
    image.cam_from_world.translation =
        10 * Eigen::Vector3d(normal(random), normal(random), normal(random));
    image.points2D.resize(i == 0 ? 0 : 20 + random() % 30);
    for (Point2D& point2D : image.points2D) {
      point2D.xy = Eigen::Vector2d(unit(random) * camera->second.width,
                                   unit(random) * camera->second.height);
    }
    free_points2D.emplace_back(image.points2D.size());
    std::iota(free_points2D.back().begin(), free_points2D.back().end(), 0);
    std::shuffle(free_points2D.back().begin(), free_points2D.back().end(), random);
    reconstruction.images[image.image_id] = image;
  }
  std::vector<Image*> images;
  for (auto& [id, image] : reconstruction.images) images.push_back(&image);
  point3D_t point3D_id = point3D_t{1} << 33;
  for (int k = 0; k < 80; ++k) {
    Point3D point3D;
    point3D_id += 1 + random() % 1000;
    std::vector<size_t> order(images.size());
    std::iota(order.begin(), order.end(), 0);
    std::shuffle(order.begin(), order.end(), random);
    const size_t track_length = 2 + random() % 3;
    for (const size_t i : order) {
      if (point3D.track.size() == track_length || free_points2D[i].empty()) continue;
      const point2D_t idx = free_points2D[i].back();
      free_points2D[i].pop_back();
      images[i]->points2D[idx].point3D_id = point3D_id;
      point3D.track.push_back({images[i]->image_id, idx});
    }
    point3D.xyz = 20 * Eigen::Vector3d(normal(random), normal(random), normal(random));
    point3D.color << random() % 256, random() % 256, random() % 256;
    point3D.error = k % 5 == 0 ? -1.0 : 2 * unit(random);
    reconstruction.points3D[point3D_id] = point3D;
  }
  return reconstruction;
}

inline bool Near(double expected, double actual, double relative) {
  return expected == actual || std::abs(expected - actual) <=
                                   relative * std::max({1.0, std::abs(expected), std::abs(actual)});
}

template <typename Vector>
inline bool NearVector(const Vector& expected, const Vector& actual, double relative) {
  for (size_t i = 0; i < static_cast<size_t>(expected.size()); ++i) {
    if (!Near(expected[i], actual[i], relative)) return false;
  }
  return true;
}

// Field by field, naming the first difference; doubles equal to within `relative` (0: exactly).
inline ::testing::AssertionResult SameReconstruction(const Reconstruction& expected,
                                                     const Reconstruction& actual,
                                                     double relative) {
  const auto differ = [](auto&&... what) {
    return ::testing::AssertionFailure() << fmt::format(what...);
  };
  if (expected.cameras.size() != actual.cameras.size() ||
      expected.images.size() != actual.images.size() ||
      expected.points3D.size() != actual.points3D.size()) {
    return differ("sizes {}/{}/{} vs {}/{}/{}", expected.cameras.size(), expected.images.size(),
                  expected.points3D.size(), actual.cameras.size(), actual.images.size(),
                  actual.points3D.size());
  }
  for (const auto& [id, camera] : expected.cameras) {
    const auto other = actual.cameras.find(id);
    if (other == actual.cameras.end()) return differ("camera {} missing", id);
    const Camera& b = other->second;
    if (b.camera_id != camera.camera_id || b.model_id != camera.model_id ||
        b.width != camera.width || b.height != camera.height ||
        b.params.size() != camera.params.size() || !NearVector(camera.params, b.params, relative)) {
      return differ("camera {} differs", id);
    }
  }
  for (const auto& [id, image] : expected.images) {
    const auto other = actual.images.find(id);
    if (other == actual.images.end()) return differ("image {} missing", id);
    const Image& b = other->second;
    if (b.image_id != image.image_id || b.name != image.name || b.camera_id != image.camera_id) {
      return differ("image {}: id, name or camera differs ('{}' vs '{}')", id, image.name, b.name);
    }
    if (!NearVector(image.cam_from_world.rotation.coeffs(), b.cam_from_world.rotation.coeffs(),
                    relative) ||
        !NearVector(image.cam_from_world.translation, b.cam_from_world.translation, relative)) {
      return differ("image {}: pose differs", id);
    }
    if (b.points2D.size() != image.points2D.size()) return differ("image {}: #points2D", id);
    for (size_t j = 0; j < image.points2D.size(); ++j) {
      if (!NearVector(image.points2D[j].xy, b.points2D[j].xy, relative) ||
          image.points2D[j].point3D_id != b.points2D[j].point3D_id) {
        return differ("image {}: 2D point {} differs", id, j);
      }
    }
  }
  for (const auto& [id, point3D] : expected.points3D) {
    const auto other = actual.points3D.find(id);
    if (other == actual.points3D.end()) return differ("point3D {} missing", id);
    const Point3D& b = other->second;
    if (!NearVector(point3D.xyz, b.xyz, relative) || point3D.color != b.color ||
        !Near(point3D.error, b.error, relative) || point3D.track.size() != b.track.size()) {
      return differ("point3D {} differs", id);
    }
    for (size_t j = 0; j < point3D.track.size(); ++j) {
      if (point3D.track[j].image_id != b.track[j].image_id ||
          point3D.track[j].point2D_idx != b.track[j].point2D_idx) {
        return differ("point3D {}: track element {} differs", id, j);
      }
    }
  }
  return ::testing::AssertionSuccess();
}

template <typename Map>
inline std::string WriteToString(void (*write)(std::ostream&, const Map&), const Map& map) {
  std::ostringstream stream;
  write(stream, map);
  return stream.str();
}

template <typename Map>
Map ReadFromString(Map (*read)(std::istream&, const std::string&), const std::string& bytes,
                   const std::string& source) {
  std::istringstream stream(bytes);
  return read(stream, source);
}

inline std::string ReadFile(const fs::path& path) {
  std::ifstream file(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(file), {});
}

inline void WriteFile(const fs::path& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary | std::ios::trunc) << bytes;
}

}  // namespace hscloc::colmap_io_testing
