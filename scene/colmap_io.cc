#include "scene/colmap_io.h"

#include <fmt/ranges.h>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <fstream>
#include <optional>
#include <vector>

#include "util/binary_io.h"
#include "util/check.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;

// A 2D point in its on-disk layout (Point2D's Eigen member cannot be copied as bytes), so that
// an image's list is one read or write.
struct BinaryPoint2D {
  double x;
  double y;
  uint64_t point3D_id;
};
static_assert(sizeof(BinaryPoint2D) == 24);

// A track is stored as TrackElement's own layout, so it is read and written in place.
static_assert(std::is_trivially_copyable_v<TrackElement> && sizeof(TrackElement) == 8 &&
              offsetof(TrackElement, point2D_idx) == 4);

// Smallest possible records, to reject a count that the rest of the file cannot hold.
constexpr uint64_t kMinCameraBytes = 4 + 4 + 8 + 8 + 3 * 8;  // SIMPLE_PINHOLE: 3 parameters
constexpr uint64_t kMinImageBytes = 4 + 4 * 8 + 3 * 8 + 4 + 1 + 8;
constexpr uint64_t kMinPoint3DBytes = 8 + 3 * 8 + 3 + 8 + 8;
// Lists are read in chunks of this many elements when the stream cannot tell its size, so a
// corrupt count fails at the end of the data instead of allocating for it up front.
constexpr uint64_t kChunkElements = 1 << 16;

std::optional<uint64_t> RemainingBytes(std::istream& stream) {
  const std::istream::pos_type start = stream.tellg();
  if (start == std::istream::pos_type(-1)) return std::nullopt;
  stream.seekg(0, std::ios::end);
  const std::istream::pos_type end = stream.tellg();
  stream.clear();
  stream.seekg(start);
  if (end == std::istream::pos_type(-1) || end < start || !stream) {
    stream.clear();
    return std::nullopt;
  }
  return static_cast<uint64_t>(end - start);
}

// Reads one binary model file and keeps count of the bytes left in it. Every `describe` names
// the record being read and is called only on failure: the reads run once per field of
// millions of records.
class BinaryModelReader {
 public:
  BinaryModelReader(std::istream& stream, const std::string& source)
      : stream_(stream), source_(source), remaining_(RemainingBytes(stream)) {}

  template <typename T, typename Describe>
  T Read(const Describe& describe, const char* field) {
    T value;
    ReadArray(&value, 1, describe, field);
    return value;
  }

  template <typename T, typename Describe>
  void ReadArray(T* values, uint64_t count, const Describe& describe, const char* field) {
    static_assert(std::is_trivially_copyable_v<T>);
    const uint64_t bytes = count * sizeof(T);
    stream_.read(reinterpret_cast<char*>(values), static_cast<std::streamsize>(bytes));
    const auto read = static_cast<uint64_t>(stream_.gcount());
    if (read != bytes) {
      ThrowInvalidArgument("{}: {}: truncated file: {} ({} bytes expected, {} read)", source_,
                           describe(), field, bytes, read);
    }
    if (remaining_) *remaining_ -= std::min(*remaining_, bytes);
  }

  // A list of `count` elements; fails before allocating when the file is too short for it.
  template <typename T, typename Describe>
  std::vector<T> ReadList(uint64_t count, const Describe& describe, const char* field) {
    CheckCount(count, sizeof(T), describe, field);
    std::vector<T> values;
    if (remaining_) {
      values.resize(count);
      ReadArray(values.data(), count, describe, field);
      return values;
    }
    for (uint64_t done = 0; done < count;) {
      const uint64_t chunk = std::min(kChunkElements, count - done);
      values.resize(done + chunk);
      ReadArray(values.data() + done, chunk, describe, field);
      done += chunk;
    }
    return values;
  }

  template <typename Describe>
  std::string ReadName(const Describe& describe) {
    std::string name = ReadBinaryCString(stream_, fmt::format("{}: {}: name", source_, describe()));
    if (remaining_) *remaining_ -= std::min<uint64_t>(*remaining_, name.size() + 1);
    return name;
  }

  // Throws unless `count` records of at least `min_bytes` each fit in the rest of the file.
  template <typename Describe>
  void CheckCount(uint64_t count, uint64_t min_bytes, const Describe& describe,
                  const char* what) const {
    if (remaining_ && count > *remaining_ / min_bytes) {
      ThrowInvalidArgument(
          "{}: {}: {} {} declared, but the {} bytes left in the file hold at most {} "
          "(truncated or corrupt file)",
          source_, describe(), count, what, *remaining_, *remaining_ / min_bytes);
    }
  }

  void ExpectEnd(uint64_t count, const char* records) {
    if (stream_.peek() == std::istream::traits_type::eof()) return;
    const std::string amount = remaining_ ? fmt::format("{} bytes", *remaining_) : "data";
    ThrowInvalidArgument("{}: {} of unexpected data after the {} {} the file declares", source_,
                         amount, count, records);
  }

 private:
  std::istream& stream_;
  const std::string& source_;
  std::optional<uint64_t> remaining_;
};

template <typename Map>
void InsertUnique(Map& map, typename Map::key_type id, typename Map::mapped_type value,
                  const std::string& source, const char* kind) {
  if (!map.emplace(id, std::move(value)).second) {
    ThrowInvalidArgument("{}: duplicate {} id {}", source, kind, id);
  }
}

template <typename Map>
Map ReadModelFile(const fs::path& path, Map (*read)(std::istream&, const std::string&)) {
  std::ifstream file(path, std::ios::binary);
  if (!file) ThrowInvalidArgument("{}: cannot open for reading", path.string());
  return read(file, path.string());
}

template <typename Map>
void WriteModelFile(const fs::path& path, const Map& map,
                    void (*write)(std::ostream&, const Map&)) {
  std::ofstream file(path, std::ios::binary | std::ios::trunc);
  if (!file) ThrowInvalidArgument("{}: cannot open for writing", path.string());
  write(file, map);
  file.flush();
  if (!file) ThrowInvalidArgument("{}: write failed", path.string());
}

}  // namespace

namespace internal {

Eigen::Quaterniond QuaternionFromColmap(double w, double x, double y, double z,
                                        const std::string& record) {
  Eigen::Quaterniond rotation(w, x, y, z);
  const double squared_norm = rotation.squaredNorm();
  if (!std::isfinite(squared_norm) || squared_norm == 0) {
    ThrowInvalidArgument("{}: quaternion ({}, {}, {}, {}) is zero or not finite", record, w, x, y,
                         z);
  }
  // Normalizing an already normalized quaternion may move it by an ulp; skipping it keeps
  // write-then-read exact.
  if (std::abs(squared_norm - 1) > 1e-14) rotation.normalize();
  return rotation;
}

void CheckCameraFrom(const Camera& camera, const std::string& source) {
  try {
    camera.Check();
  } catch (const std::invalid_argument& error) {
    ThrowInvalidArgument("{}: {}", source, error.what());
  }
}

}  // namespace internal

std::map<camera_t, Camera> ReadCamerasBinary(std::istream& stream, const std::string& source) {
  BinaryModelReader reader(stream, source);
  const auto header = [] { return std::string("header"); };
  const auto count = reader.Read<uint64_t>(header, "number of cameras");
  reader.CheckCount(count, kMinCameraBytes, header, "cameras");
  std::map<camera_t, Camera> cameras;
  for (uint64_t i = 0; i < count; ++i) {
    const auto at_index = [&] { return fmt::format("camera record {} of {}", i + 1, count); };
    Camera camera;
    camera.camera_id = reader.Read<camera_t>(at_index, "camera_id");
    const auto at_id = [&] { return fmt::format("camera {}", camera.camera_id); };
    const auto model_id = reader.Read<int32_t>(at_id, "model_id");
    if (!IsKnownCameraModelId(model_id)) {
      ThrowInvalidArgument("{}: {}: unknown camera model id {}", source, at_id(), model_id);
    }
    camera.model_id = static_cast<CameraModelId>(model_id);
    camera.width = reader.Read<uint64_t>(at_id, "width");
    camera.height = reader.Read<uint64_t>(at_id, "height");
    camera.params.resize(CameraModelNumParams(camera.model_id));
    reader.ReadArray(camera.params.data(), camera.params.size(), at_id, "params");
    internal::CheckCameraFrom(camera, source);
    InsertUnique(cameras, camera.camera_id, std::move(camera), source, "camera");
  }
  reader.ExpectEnd(count, "cameras");
  return cameras;
}

std::map<image_t, Image> ReadImagesBinary(std::istream& stream, const std::string& source) {
  BinaryModelReader reader(stream, source);
  const auto header = [] { return std::string("header"); };
  const auto count = reader.Read<uint64_t>(header, "number of images");
  reader.CheckCount(count, kMinImageBytes, header, "images");
  std::map<image_t, Image> images;
  for (uint64_t i = 0; i < count; ++i) {
    const auto at_index = [&] { return fmt::format("image record {} of {}", i + 1, count); };
    Image image;
    image.image_id = reader.Read<image_t>(at_index, "image_id");
    const auto at_id = [&] {
      return image.name.empty() ? fmt::format("image {}", image.image_id)
                                : fmt::format("image {} (name '{}')", image.image_id, image.name);
    };
    double qvec[4];
    reader.ReadArray(qvec, 4, at_id, "qvec");
    image.cam_from_world.rotation = internal::QuaternionFromColmap(
        qvec[0], qvec[1], qvec[2], qvec[3], fmt::format("{}: {}", source, at_id()));
    reader.ReadArray(image.cam_from_world.translation.data(), 3, at_id, "tvec");
    image.camera_id = reader.Read<camera_t>(at_id, "camera_id");
    image.name = reader.ReadName(at_id);
    const auto num_points2D = reader.Read<uint64_t>(at_id, "number of points2D");
    const auto points2D = reader.ReadList<BinaryPoint2D>(num_points2D, at_id, "points2D");
    image.points2D.resize(points2D.size());
    for (size_t j = 0; j < points2D.size(); ++j) {
      image.points2D[j].xy = Eigen::Vector2d(points2D[j].x, points2D[j].y);
      image.points2D[j].point3D_id = points2D[j].point3D_id;
    }
    InsertUnique(images, image.image_id, std::move(image), source, "image");
  }
  reader.ExpectEnd(count, "images");
  return images;
}

std::map<point3D_t, Point3D> ReadPoints3DBinary(std::istream& stream, const std::string& source) {
  BinaryModelReader reader(stream, source);
  const auto header = [] { return std::string("header"); };
  const auto count = reader.Read<uint64_t>(header, "number of points3D");
  reader.CheckCount(count, kMinPoint3DBytes, header, "points3D");
  std::map<point3D_t, Point3D> points3D;
  for (uint64_t i = 0; i < count; ++i) {
    const auto at_index = [&] { return fmt::format("point3D record {} of {}", i + 1, count); };
    const auto point3D_id = reader.Read<point3D_t>(at_index, "point3D_id");
    const auto at_id = [&] { return fmt::format("point3D {}", point3D_id); };
    Point3D point3D;
    reader.ReadArray(point3D.xyz.data(), 3, at_id, "xyz");
    reader.ReadArray(point3D.color.data(), 3, at_id, "rgb");
    point3D.error = reader.Read<double>(at_id, "error");
    const auto track_length = reader.Read<uint64_t>(at_id, "track length");
    point3D.track = reader.ReadList<TrackElement>(track_length, at_id, "track elements");
    InsertUnique(points3D, point3D_id, std::move(point3D), source, "point3D");
  }
  reader.ExpectEnd(count, "points3D");
  return points3D;
}

void WriteCamerasBinary(std::ostream& stream, const std::map<camera_t, Camera>& cameras) {
  WriteBinary<uint64_t>(stream, cameras.size());
  for (const auto& [camera_id, camera] : cameras) {
    WriteBinary<camera_t>(stream, camera_id);
    WriteBinary<int32_t>(stream, static_cast<int32_t>(camera.model_id));
    WriteBinary<uint64_t>(stream, camera.width);
    WriteBinary<uint64_t>(stream, camera.height);
    WriteBinaryArray(stream, camera.params.data(), camera.params.size());
  }
}

void WriteImagesBinary(std::ostream& stream, const std::map<image_t, Image>& images) {
  WriteBinary<uint64_t>(stream, images.size());
  std::vector<BinaryPoint2D> points2D;
  for (const auto& [image_id, image] : images) {
    if (image.name.find('\0') != std::string::npos) {
      ThrowInvalidArgument(
          "image {}: its name holds a NUL character, which ends names in images.bin", image_id);
    }
  }
  for (const auto& [image_id, image] : images) {
    WriteBinary<image_t>(stream, image_id);
    const Eigen::Quaterniond& rotation = image.cam_from_world.rotation;
    const double qvec[4] = {rotation.w(), rotation.x(), rotation.y(), rotation.z()};
    WriteBinaryArray(stream, qvec, 4);
    WriteBinaryArray(stream, image.cam_from_world.translation.data(), 3);
    WriteBinary<camera_t>(stream, image.camera_id);
    stream.write(image.name.c_str(), static_cast<std::streamsize>(image.name.size() + 1));
    WriteBinary<uint64_t>(stream, image.points2D.size());
    points2D.clear();
    for (const Point2D& point2D : image.points2D) {
      points2D.push_back({point2D.xy.x(), point2D.xy.y(), point2D.point3D_id});
    }
    WriteBinaryArray(stream, points2D.data(), points2D.size());
  }
}

void WritePoints3DBinary(std::ostream& stream, const std::map<point3D_t, Point3D>& points3D) {
  WriteBinary<uint64_t>(stream, points3D.size());
  for (const auto& [point3D_id, point3D] : points3D) {
    WriteBinary<point3D_t>(stream, point3D_id);
    WriteBinaryArray(stream, point3D.xyz.data(), 3);
    WriteBinaryArray(stream, point3D.color.data(), 3);
    WriteBinary<double>(stream, point3D.error);
    WriteBinary<uint64_t>(stream, point3D.track.size());
    WriteBinaryArray(stream, point3D.track.data(), point3D.track.size());
  }
}

ColmapFormat DetectColmapFormat(const fs::path& dir) {
  if (!fs::is_directory(dir)) {
    ThrowInvalidArgument("COLMAP model '{}': not a directory", dir.string());
  }
  const auto missing = [&](const char* extension) {
    std::vector<std::string> names;
    for (const char* stem : {"cameras", "images", "points3D"}) {
      const std::string name = std::string(stem) + extension;
      if (!fs::is_regular_file(dir / name)) names.push_back(name);
    }
    return names;
  };
  const std::vector<std::string> missing_binary = missing(".bin");
  if (missing_binary.empty()) return ColmapFormat::kBinary;
  const std::vector<std::string> missing_text = missing(".txt");
  if (missing_text.empty()) return ColmapFormat::kText;
  ThrowInvalidArgument("COLMAP model '{}': no complete model: binary lacks {}, text lacks {}",
                       dir.string(), fmt::join(missing_binary, ", "),
                       fmt::join(missing_text, ", "));
}

Reconstruction ReadColmapModel(const fs::path& dir) {
  Reconstruction reconstruction;
  if (DetectColmapFormat(dir) == ColmapFormat::kBinary) {
    reconstruction.cameras = ReadModelFile(dir / "cameras.bin", &ReadCamerasBinary);
    reconstruction.images = ReadModelFile(dir / "images.bin", &ReadImagesBinary);
    reconstruction.points3D = ReadModelFile(dir / "points3D.bin", &ReadPoints3DBinary);
  } else {
    reconstruction.cameras = ReadModelFile(dir / "cameras.txt", &ReadCamerasText);
    reconstruction.images = ReadModelFile(dir / "images.txt", &ReadImagesText);
    reconstruction.points3D = ReadModelFile(dir / "points3D.txt", &ReadPoints3DText);
  }
  try {
    reconstruction.Check();
  } catch (const std::invalid_argument& error) {
    ThrowInvalidArgument("COLMAP model '{}': {}", dir.string(), error.what());
  }
  return reconstruction;
}

void WriteColmapModel(const Reconstruction& reconstruction, const fs::path& dir,
                      ColmapFormat format) {
  fs::create_directories(dir);
  if (format == ColmapFormat::kBinary) {
    WriteModelFile(dir / "cameras.bin", reconstruction.cameras, &WriteCamerasBinary);
    WriteModelFile(dir / "images.bin", reconstruction.images, &WriteImagesBinary);
    WriteModelFile(dir / "points3D.bin", reconstruction.points3D, &WritePoints3DBinary);
  } else {
    WriteModelFile(dir / "cameras.txt", reconstruction.cameras, &WriteCamerasText);
    WriteModelFile(dir / "images.txt", reconstruction.images, &WriteImagesText);
    WriteModelFile(dir / "points3D.txt", reconstruction.points3D, &WritePoints3DText);
  }
}

}  // namespace hscloc
