#include "scene/scene_io.h"

#include <algorithm>
#include <istream>
#include <ostream>

#include "util/binary_io.h"
#include "util/check.h"
#include "util/half.h"

namespace hscloc {
namespace {

constexpr uint32_t kGeometryMagic = 0x47435348;      // "HSCG"
constexpr uint32_t kObservationsMagic = 0x4f435348;  // "HSCO"
constexpr uint32_t kVersion = 1;
// Bounds that no real map reaches; a count beyond them is corruption, not a big map.
constexpr uint64_t kMaxCount = uint64_t{1} << 34;
constexpr uint64_t kMaxNameLength = 4096;

void ReadHeader(std::istream& stream, const std::string& source, uint32_t magic) {
  if (ReadBinary<uint32_t>(stream, source + ": magic") != magic) {
    ThrowInvalidArgument("{}: not an hscloc scene blob of this kind (wrong magic)", source);
  }
  const auto version = ReadBinary<uint32_t>(stream, source + ": version");
  if (version != kVersion) {
    ThrowInvalidArgument("{}: version {} (this build reads version {})", source, version, kVersion);
  }
}

uint64_t ReadCount(std::istream& stream, const std::string& what) {
  const auto count = ReadBinary<uint64_t>(stream, what);
  if (count > kMaxCount) ThrowInvalidArgument("{}: impossible count {}", what, count);
  return count;
}

}  // namespace

void WriteSceneGeometry(std::ostream& stream, const Scene& scene) {
  WriteBinary(stream, kGeometryMagic);
  WriteBinary(stream, kVersion);
  WriteBinary<uint64_t>(stream, scene.cameras.size());
  for (const auto& [camera_id, camera] : scene.cameras) {
    WriteBinary(stream, camera.camera_id);
    WriteBinary(stream, static_cast<int32_t>(camera.model_id));
    WriteBinary(stream, camera.width);
    WriteBinary(stream, camera.height);
    WriteBinary<uint64_t>(stream, camera.params.size());
    WriteBinaryArray(stream, camera.params.data(), camera.params.size());
  }
  WriteBinary<uint64_t>(stream, scene.images.size());
  for (const SceneImage& image : scene.images) {
    WriteBinary(stream, image.image_id);
    WriteBinary(stream, image.camera_id);
    WriteBinary<uint64_t>(stream, image.name.size());
    stream.write(image.name.data(), static_cast<std::streamsize>(image.name.size()));
    const Eigen::Quaterniond& q = image.cam_from_world.rotation;
    const double pose[7] = {q.w(),
                            q.x(),
                            q.y(),
                            q.z(),
                            image.cam_from_world.translation.x(),
                            image.cam_from_world.translation.y(),
                            image.cam_from_world.translation.z()};
    WriteBinaryArray(stream, pose, 7);
  }
  WriteBinary<uint64_t>(stream, scene.points.size());
  WriteBinaryArray(stream, scene.point3D_ids.data(), scene.point3D_ids.size());
  for (const Eigen::Vector3d& point : scene.points) WriteBinaryArray(stream, point.data(), 3);
}

Scene ReadSceneGeometry(std::istream& stream, const std::string& source) {
  ReadHeader(stream, source, kGeometryMagic);
  Scene scene;
  const uint64_t num_cameras = ReadCount(stream, source + ": camera count");
  for (uint64_t i = 0; i < num_cameras; ++i) {
    const std::string what = fmt::format("{}: camera {}", source, i);
    Camera camera;
    camera.camera_id = ReadBinary<camera_t>(stream, what);
    const auto model_id = ReadBinary<int32_t>(stream, what);
    if (!IsKnownCameraModelId(model_id)) {
      ThrowInvalidArgument("{}: unknown camera model id {}", what, model_id);
    }
    camera.model_id = static_cast<CameraModelId>(model_id);
    camera.width = ReadBinary<uint64_t>(stream, what);
    camera.height = ReadBinary<uint64_t>(stream, what);
    const uint64_t num_params = ReadBinary<uint64_t>(stream, what);
    if (num_params != CameraModelNumParams(camera.model_id)) {
      ThrowInvalidArgument("{}: {} parameters for model {}", what, num_params,
                           CameraModelName(camera.model_id));
    }
    camera.params.resize(num_params);
    ReadBinaryArray(stream, camera.params.data(), num_params, what);
    camera.Check();
    if (!scene.cameras.emplace(camera.camera_id, camera).second) {
      ThrowInvalidArgument("{}: duplicate camera id {}", what, camera.camera_id);
    }
  }
  const uint64_t num_images = ReadCount(stream, source + ": image count");
  scene.images.resize(num_images);
  for (uint64_t i = 0; i < num_images; ++i) {
    const std::string what = fmt::format("{}: image {}", source, i);
    SceneImage& image = scene.images[i];
    image.image_id = ReadBinary<image_t>(stream, what);
    image.camera_id = ReadBinary<camera_t>(stream, what);
    if (scene.cameras.count(image.camera_id) == 0) {
      ThrowInvalidArgument("{}: unknown camera id {}", what, image.camera_id);
    }
    const auto name_length = ReadBinary<uint64_t>(stream, what);
    if (name_length > kMaxNameLength) {
      ThrowInvalidArgument("{}: name of {} characters", what, name_length);
    }
    image.name.resize(name_length);
    ReadBinaryArray(stream, image.name.data(), name_length, what);
    double pose[7];
    ReadBinaryArray(stream, pose, 7, what);
    image.cam_from_world.rotation = Eigen::Quaterniond(pose[0], pose[1], pose[2], pose[3]);
    image.cam_from_world.translation = Eigen::Vector3d(pose[4], pose[5], pose[6]);
  }
  const uint64_t num_points = ReadCount(stream, source + ": point count");
  scene.point3D_ids.resize(num_points);
  ReadBinaryArray(stream, scene.point3D_ids.data(), num_points, source + ": point ids");
  scene.points.resize(num_points);
  for (uint64_t p = 0; p < num_points; ++p) {
    ReadBinaryArray(stream, scene.points[p].data(), 3, source + ": point positions");
  }
  if (stream.peek() != std::char_traits<char>::eof()) {
    ThrowInvalidArgument("{}: unexpected bytes after the last point", source);
  }
  scene.RebuildIndex();
  return scene;
}

SceneObservationsWriter::SceneObservationsWriter(std::ostream& stream, const Scene& scene,
                                                 int64_t dimension)
    : stream_(stream), expected_rows_(scene.NumObservations()), dimension_(dimension) {
  THROW_CHECK_MSG(dimension >= 0, "SceneObservationsWriter: dimension {}", dimension);
  WriteBinary(stream, kObservationsMagic);
  WriteBinary(stream, kVersion);
  WriteBinary<uint64_t>(stream, scene.NumObservations());
  WriteBinary<uint64_t>(stream, static_cast<uint64_t>(dimension));
  WriteBinaryArray(stream, scene.observation_image_indices.data(), scene.NumObservations());
  WriteBinaryArray(stream, scene.observation_point_indices.data(), scene.NumObservations());
}

void SceneObservationsWriter::Append(const DescriptorMatrix& rows) {
  THROW_CHECK_MSG(rows.cols() == dimension_ && rows_ + rows.rows() <= expected_rows_,
                  "SceneObservationsWriter: {} rows of dimension {} after {} of {} of dimension {}",
                  rows.rows(), rows.cols(), rows_, expected_rows_, dimension_);
  // Converted in blocks, so that a whole scene's rows need no second copy.
  constexpr Eigen::Index kBlockRows = 4096;
  for (Eigen::Index begin = 0; begin < rows.rows(); begin += kBlockRows) {
    const Eigen::Index end = std::min(rows.rows(), begin + kBlockRows);
    halves_.resize(static_cast<size_t>((end - begin) * rows.cols()));
    for (Eigen::Index row = begin; row < end; ++row) {
      for (Eigen::Index d = 0; d < rows.cols(); ++d) {
        halves_[(row - begin) * rows.cols() + d] = FloatToHalfBits(rows(row, d));
      }
    }
    WriteBinaryArray(stream_, halves_.data(), halves_.size());
  }
  rows_ += rows.rows();
}

void SceneObservationsWriter::Finish() const {
  THROW_CHECK_MSG(rows_ == expected_rows_, "SceneObservationsWriter: {} of {} rows written", rows_,
                  expected_rows_);
}

void WriteSceneObservations(std::ostream& stream, const Scene& scene) {
  SceneObservationsWriter writer(stream, scene, scene.Dimension());
  writer.Append(scene.observation_descriptors);
  writer.Finish();
}

void ReadSceneObservations(std::istream& stream, const std::string& source, Scene& scene) {
  ReadHeader(stream, source, kObservationsMagic);
  const uint64_t count = ReadCount(stream, source + ": observation count");
  const uint64_t dimension = ReadBinary<uint64_t>(stream, source + ": dimension");
  if (count > 0 && (dimension == 0 || dimension > 65536)) {
    ThrowInvalidArgument("{}: impossible descriptor dimension {}", source, dimension);
  }
  scene.observation_image_indices.resize(count);
  scene.observation_point_indices.resize(count);
  ReadBinaryArray(stream, scene.observation_image_indices.data(), count,
                  source + ": image indices");
  ReadBinaryArray(stream, scene.observation_point_indices.data(), count,
                  source + ": point indices");
  for (uint64_t i = 0; i < count; ++i) {
    if (scene.observation_image_indices[i] >= scene.NumImages() ||
        scene.observation_point_indices[i] >= scene.NumPoints()) {
      ThrowInvalidArgument("{}: observation {} names image {} / point {} of {} / {}", source, i,
                           scene.observation_image_indices[i], scene.observation_point_indices[i],
                           scene.NumImages(), scene.NumPoints());
    }
  }
  scene.observation_descriptors.resize(static_cast<Eigen::Index>(count),
                                       static_cast<Eigen::Index>(dimension));
  std::vector<uint16_t> halves(dimension);
  for (uint64_t row = 0; row < count; ++row) {
    ReadBinaryArray(stream, halves.data(), dimension, source + ": descriptors");
    for (uint64_t d = 0; d < dimension; ++d) {
      scene.observation_descriptors(row, d) = HalfBitsToFloat(halves[d]);
    }
  }
  if (stream.peek() != std::char_traits<char>::eof()) {
    ThrowInvalidArgument("{}: unexpected bytes after the last observation", source);
  }
}

}  // namespace hscloc
