// The text half of colmap_io.h.
#include <fmt/format.h>

#include <algorithm>
#include <charconv>
#include <istream>
#include <iterator>
#include <limits>
#include <map>
#include <optional>
#include <ostream>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

#include "scene/colmap_io.h"
#include "util/check.h"

namespace hscloc {
namespace {

// Reads a text model line by line, split at whitespace, keeping the line number for errors.
// Every `describe` names the record on the line and is called only on failure.
class TextModelReader {
 public:
  TextModelReader(std::istream& stream, const std::string& source)
      : stream_(stream), source_(source) {}

  // Moves to the next line that is neither blank nor a comment; false at the end of the stream.
  // Remembers the count that a COLMAP header comment ("# Number of images: 4, ...") declares.
  bool NextRecord() {
    while (NextLine()) {
      if (tokens_.empty()) continue;
      if (tokens_[0].front() != '#') return true;
      if (tokens_.size() >= 5 && tokens_[0] == "#" && tokens_[1] == "Number" &&
          tokens_[2] == "of" && tokens_[3].back() == ':') {
        std::string_view text = tokens_[4];
        if (text.back() == ',') text.remove_suffix(1);
        uint64_t count = 0;
        const auto [end, error] = std::from_chars(text.data(), text.data() + text.size(), count);
        if (error == std::errc() && end == text.data() + text.size()) declared_count_ = count;
      }
    }
    return false;
  }

  // Throws when a header comment declared a count other than the `count` records read: the
  // text format has no other way to tell a file cut at a line boundary.
  void ExpectDeclaredCount(size_t count, const char* records) const {
    if (declared_count_ && *declared_count_ != count) {
      ThrowInvalidArgument("{}: the header declares {} {}, the file holds {} (truncated file?)",
                           source_, *declared_count_, records, count);
    }
  }

  // Moves to the very next line, blank or not; false at the end of the stream.
  bool NextLine() {
    if (!std::getline(stream_, line_)) {
      if (stream_.bad()) ThrowInvalidArgument("{}:{}: read error", source_, line_number_);
      return false;
    }
    ++line_number_;
    tokens_.clear();
    constexpr std::string_view kWhitespace = " \t\r\v\f";
    const std::string_view line = line_;
    for (size_t start = line.find_first_not_of(kWhitespace); start != std::string_view::npos;) {
      const size_t end = std::min(line.find_first_of(kWhitespace, start), line.size());
      tokens_.push_back(line.substr(start, end - start));
      start = line.find_first_not_of(kWhitespace, end);
    }
    return true;
  }

  const std::vector<std::string_view>& tokens() const { return tokens_; }

  // "images.txt:12".
  std::string Location() const { return fmt::format("{}:{}", source_, line_number_); }
  // "images.txt:12: image 4 (name 'a.jpg')".
  template <typename Describe>
  std::string Where(const Describe& describe) const {
    return fmt::format("{}: {}", Location(), describe());
  }

  template <typename Describe, typename... Args>
  [[noreturn]] void Fail(const Describe& describe, fmt::format_string<Args...> format,
                         Args&&... args) const {
    ThrowInvalidArgument("{}: {}", Where(describe),
                         fmt::format(format, std::forward<Args>(args)...));
  }

  // Parses token `index` in full as T; `field` names it in the error.
  template <typename T, typename Describe>
  T Parse(size_t index, const Describe& describe, const char* field) const {
    const std::string_view token = tokens_[index];
    T value{};
    const auto [end, error] = std::from_chars(token.data(), token.data() + token.size(), value);
    if (error == std::errc() && end == token.data() + token.size()) return value;
    if constexpr (std::is_floating_point_v<T>) {
      Fail(describe, "{} (field {}) '{}' is not a valid number", field, index + 1, token);
    } else {
      Fail(describe, "{} (field {}) '{}' is not an integer in [{}, {}]", field, index + 1, token,
           +std::numeric_limits<T>::min(), +std::numeric_limits<T>::max());
    }
  }

 private:
  std::istream& stream_;
  const std::string& source_;
  std::string line_;
  size_t line_number_ = 0;
  std::vector<std::string_view> tokens_;
  std::optional<uint64_t> declared_count_;
};

template <typename Map>
void InsertUnique(Map& map, typename Map::key_type id, typename Map::mapped_type value,
                  const std::string& where, const char* kind) {
  if (!map.emplace(id, std::move(value)).second) {
    ThrowInvalidArgument("{}: duplicate {} id {}", where, kind, id);
  }
}

// Text is formatted into a buffer and handed to the stream in large pieces: formatting through
// the stream's operator<< is several times slower for million-point models.
class TextModelWriter {
 public:
  explicit TextModelWriter(std::ostream& stream) : stream_(stream) {}
  ~TextModelWriter() { Flush(); }

  template <typename... Args>
  void Write(fmt::format_string<Args...> format, Args&&... args) {
    fmt::format_to(std::back_inserter(buffer_), format, std::forward<Args>(args)...);
  }

  // Ends a line, and passes the buffer on once it is large.
  void EndLine() {
    buffer_.push_back('\n');
    if (buffer_.size() > (1 << 20)) Flush();
  }

 private:
  void Flush() {
    stream_.write(buffer_.data(), static_cast<std::streamsize>(buffer_.size()));
    buffer_.clear();
  }

  std::ostream& stream_;
  fmt::memory_buffer buffer_;
};

}  // namespace

std::map<camera_t, Camera> ReadCamerasText(std::istream& stream, const std::string& source) {
  TextModelReader reader(stream, source);
  std::map<camera_t, Camera> cameras;
  while (reader.NextRecord()) {
    const auto& tokens = reader.tokens();
    const auto describe = [&] { return fmt::format("camera {}", tokens[0]); };
    if (tokens.size() < 4) {
      reader.Fail(describe, "expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS..., found {} fields",
                  tokens.size());
    }
    Camera camera;
    camera.camera_id = reader.Parse<camera_t>(0, describe, "CAMERA_ID");
    try {
      camera.model_id = CameraModelIdFromName(std::string(tokens[1]));
    } catch (const std::invalid_argument& error) {
      reader.Fail(describe, "{}", error.what());
    }
    const size_t num_params = CameraModelNumParams(camera.model_id);
    if (tokens.size() - 4 != num_params) {
      reader.Fail(describe, "model {} takes {} parameters, {} given", tokens[1], num_params,
                  tokens.size() - 4);
    }
    camera.width = reader.Parse<uint64_t>(2, describe, "WIDTH");
    camera.height = reader.Parse<uint64_t>(3, describe, "HEIGHT");
    for (size_t i = 0; i < num_params; ++i) {
      camera.params.push_back(reader.Parse<double>(4 + i, describe, "PARAMS"));
    }
    internal::CheckCameraFrom(camera, reader.Location());
    InsertUnique(cameras, camera.camera_id, std::move(camera), reader.Where(describe), "camera");
  }
  reader.ExpectDeclaredCount(cameras.size(), "cameras");
  return cameras;
}

std::map<image_t, Image> ReadImagesText(std::istream& stream, const std::string& source) {
  TextModelReader reader(stream, source);
  std::map<image_t, Image> images;
  while (reader.NextRecord()) {
    const auto& tokens = reader.tokens();
    // Copies: the POINTS2D line replaces the tokens' text.
    const std::string id_token(tokens[0]);
    const std::string name_token(tokens.size() >= 10 ? tokens[9] : std::string_view());
    const auto describe = [&] {
      return name_token.empty() ? fmt::format("image {}", id_token)
                                : fmt::format("image {} (name '{}')", id_token, name_token);
    };
    if (tokens.size() != 10) {
      reader.Fail(describe,
                  "expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, found {} fields "
                  "(names cannot contain whitespace in the text format)",
                  tokens.size());
    }
    Image image;
    image.image_id = reader.Parse<image_t>(0, describe, "IMAGE_ID");
    const double qw = reader.Parse<double>(1, describe, "QW");
    const double qx = reader.Parse<double>(2, describe, "QX");
    const double qy = reader.Parse<double>(3, describe, "QY");
    const double qz = reader.Parse<double>(4, describe, "QZ");
    image.cam_from_world.rotation =
        internal::QuaternionFromColmap(qw, qx, qy, qz, reader.Where(describe));
    image.cam_from_world.translation = Eigen::Vector3d(reader.Parse<double>(5, describe, "TX"),
                                                       reader.Parse<double>(6, describe, "TY"),
                                                       reader.Parse<double>(7, describe, "TZ"));
    image.camera_id = reader.Parse<camera_t>(8, describe, "CAMERA_ID");
    image.name = name_token;
    const std::string where_image = reader.Where(describe);

    if (!reader.NextLine()) {
      reader.Fail(describe, "the file ends before the image's POINTS2D line");
    }
    const auto& points = reader.tokens();
    if (points.size() % 3 != 0) {
      reader.Fail(describe, "POINTS2D line holds {} fields, not a multiple of 3 (X Y POINT3D_ID)",
                  points.size());
    }
    image.points2D.resize(points.size() / 3);
    for (size_t j = 0; j < image.points2D.size(); ++j) {
      Point2D& point2D = image.points2D[j];
      point2D.xy = Eigen::Vector2d(reader.Parse<double>(3 * j, describe, "POINTS2D X"),
                                   reader.Parse<double>(3 * j + 1, describe, "POINTS2D Y"));
      if (points[3 * j + 2] != "-1") {
        point2D.point3D_id = reader.Parse<point3D_t>(3 * j + 2, describe, "POINTS2D POINT3D_ID");
      }
    }
    InsertUnique(images, image.image_id, std::move(image), where_image, "image");
  }
  reader.ExpectDeclaredCount(images.size(), "images");
  return images;
}

std::map<point3D_t, Point3D> ReadPoints3DText(std::istream& stream, const std::string& source) {
  TextModelReader reader(stream, source);
  std::map<point3D_t, Point3D> points3D;
  while (reader.NextRecord()) {
    const auto& tokens = reader.tokens();
    const auto describe = [&] { return fmt::format("point3D {}", tokens[0]); };
    if (tokens.size() < 8 || tokens.size() % 2 != 0) {
      reader.Fail(describe,
                  "expected POINT3D_ID X Y Z R G B ERROR and (IMAGE_ID POINT2D_IDX) pairs, "
                  "found {} fields",
                  tokens.size());
    }
    const auto point3D_id = reader.Parse<point3D_t>(0, describe, "POINT3D_ID");
    Point3D point3D;
    point3D.xyz = Eigen::Vector3d(reader.Parse<double>(1, describe, "X"),
                                  reader.Parse<double>(2, describe, "Y"),
                                  reader.Parse<double>(3, describe, "Z"));
    point3D.color << reader.Parse<uint8_t>(4, describe, "R"),
        reader.Parse<uint8_t>(5, describe, "G"), reader.Parse<uint8_t>(6, describe, "B");
    point3D.error = reader.Parse<double>(7, describe, "ERROR");
    point3D.track.resize((tokens.size() - 8) / 2);
    for (size_t j = 0; j < point3D.track.size(); ++j) {
      point3D.track[j].image_id = reader.Parse<image_t>(8 + 2 * j, describe, "TRACK IMAGE_ID");
      point3D.track[j].point2D_idx =
          reader.Parse<point2D_t>(9 + 2 * j, describe, "TRACK POINT2D_IDX");
    }
    InsertUnique(points3D, point3D_id, std::move(point3D), reader.Where(describe), "point3D");
  }
  reader.ExpectDeclaredCount(points3D.size(), "points3D");
  return points3D;
}

void WriteCamerasText(std::ostream& stream, const std::map<camera_t, Camera>& cameras) {
  TextModelWriter writer(stream);
  writer.Write(
      "# Camera list with one line of data per camera:\n"
      "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
      "# Number of cameras: {}\n",
      cameras.size());
  for (const auto& [camera_id, camera] : cameras) {
    writer.Write("{} {} {} {}", camera_id, CameraModelName(camera.model_id), camera.width,
                 camera.height);
    for (const double param : camera.params) writer.Write(" {:.17g}", param);
    writer.EndLine();
  }
}

void WriteImagesText(std::ostream& stream, const std::map<image_t, Image>& images) {
  size_t num_observations = 0;
  for (const auto& [image_id, image] : images) {
    if (image.name.empty() ||
        image.name.find_first_of(std::string_view(" \t\n\r\v\f")) != std::string::npos) {
      ThrowInvalidArgument(
          "image {}: name '{}' cannot be written as text: the format needs a name without "
          "whitespace",
          image_id, image.name);
    }
    for (const Point2D& point2D : image.points2D) num_observations += point2D.HasPoint3D();
  }
  TextModelWriter writer(stream);
  writer.Write(
      "# Image list with two lines of data per image:\n"
      "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
      "#   POINTS2D[] as (X, Y, POINT3D_ID)\n"
      "# Number of images: {}, mean observations per image: {:.17g}\n",
      images.size(), images.empty() ? 0.0 : static_cast<double>(num_observations) / images.size());
  for (const auto& [image_id, image] : images) {
    const Eigen::Quaterniond& rotation = image.cam_from_world.rotation;
    const Eigen::Vector3d& translation = image.cam_from_world.translation;
    writer.Write("{} {:.17g} {:.17g} {:.17g} {:.17g} {:.17g} {:.17g} {:.17g} {} {}", image_id,
                 rotation.w(), rotation.x(), rotation.y(), rotation.z(), translation.x(),
                 translation.y(), translation.z(), image.camera_id, image.name);
    writer.EndLine();
    const char* separator = "";
    for (const Point2D& point2D : image.points2D) {
      writer.Write("{}{:.17g} {:.17g} ", separator, point2D.xy.x(), point2D.xy.y());
      if (point2D.HasPoint3D()) {
        writer.Write("{}", point2D.point3D_id);
      } else {
        writer.Write("-1");
      }
      separator = " ";
    }
    writer.EndLine();
  }
}

void WritePoints3DText(std::ostream& stream, const std::map<point3D_t, Point3D>& points3D) {
  size_t num_observations = 0;
  for (const auto& [point3D_id, point3D] : points3D) num_observations += point3D.track.size();
  TextModelWriter writer(stream);
  writer.Write(
      "# 3D point list with one line of data per point:\n"
      "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
      "# Number of points: {}, mean track length: {:.17g}\n",
      points3D.size(),
      points3D.empty() ? 0.0 : static_cast<double>(num_observations) / points3D.size());
  for (const auto& [point3D_id, point3D] : points3D) {
    writer.Write("{} {:.17g} {:.17g} {:.17g} {} {} {} {:.17g}", point3D_id, point3D.xyz.x(),
                 point3D.xyz.y(), point3D.xyz.z(), point3D.color[0], point3D.color[1],
                 point3D.color[2], point3D.error);
    for (const TrackElement& element : point3D.track) {
      writer.Write(" {} {}", element.image_id, element.point2D_idx);
    }
    writer.EndLine();
  }
}

}  // namespace hscloc
