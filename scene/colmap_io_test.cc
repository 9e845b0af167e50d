#include "scene/colmap_io.h"

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <numeric>
#include <random>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "util/testing.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

Camera MakeCamera(camera_t camera_id, CameraModelId model_id, std::mt19937& random) {
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
Reconstruction RandomReconstruction(uint32_t seed) {
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

bool Near(double expected, double actual, double relative) {
  return expected == actual || std::abs(expected - actual) <=
                                   relative * std::max({1.0, std::abs(expected), std::abs(actual)});
}

template <typename Vector>
bool NearVector(const Vector& expected, const Vector& actual, double relative) {
  for (size_t i = 0; i < static_cast<size_t>(expected.size()); ++i) {
    if (!Near(expected[i], actual[i], relative)) return false;
  }
  return true;
}

// Field by field, naming the first difference; doubles equal to within `relative` (0: exactly).
::testing::AssertionResult SameReconstruction(const Reconstruction& expected,
                                              const Reconstruction& actual, double relative) {
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
std::string WriteToString(void (*write)(std::ostream&, const Map&), const Map& map) {
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

std::string ReadFile(const fs::path& path) {
  std::ifstream file(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(file), {});
}

void WriteFile(const fs::path& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary | std::ios::trunc) << bytes;
}

TEST(ColmapIo, RandomReconstructionIsConsistent) {
  const Reconstruction reconstruction = RandomReconstruction(1);
  EXPECT_NO_THROW(reconstruction.Check());
  EXPECT_GT(reconstruction.NumObservations(), 150u);
}

TEST(ColmapIo, BinaryRoundTripIsExact) {
  const Reconstruction expected = RandomReconstruction(2);
  Reconstruction actual;
  actual.cameras = ReadFromString(&ReadCamerasBinary,
                                  WriteToString(&WriteCamerasBinary, expected.cameras), "c.bin");
  actual.images = ReadFromString(&ReadImagesBinary,
                                 WriteToString(&WriteImagesBinary, expected.images), "i.bin");
  actual.points3D = ReadFromString(&ReadPoints3DBinary,
                                   WriteToString(&WritePoints3DBinary, expected.points3D), "p.bin");
  EXPECT_TRUE(SameReconstruction(expected, actual, 0));
}

TEST(ColmapIo, TextRoundTripIsExact) {
  const Reconstruction expected = RandomReconstruction(3);
  Reconstruction actual;
  actual.cameras =
      ReadFromString(&ReadCamerasText, WriteToString(&WriteCamerasText, expected.cameras), "c.txt");
  actual.images =
      ReadFromString(&ReadImagesText, WriteToString(&WriteImagesText, expected.images), "i.txt");
  actual.points3D = ReadFromString(&ReadPoints3DText,
                                   WriteToString(&WritePoints3DText, expected.points3D), "p.txt");
  EXPECT_TRUE(SameReconstruction(expected, actual, 0));
}

TEST(ColmapIo, ModelDirectoryRoundTripsInBothFormats) {
  const testing::TempDir temp;
  const Reconstruction expected = RandomReconstruction(4);
  for (const ColmapFormat format : {ColmapFormat::kBinary, ColmapFormat::kText}) {
    const fs::path dir = temp / (format == ColmapFormat::kBinary ? "bin" : "txt");
    WriteColmapModel(expected, dir, format);
    EXPECT_EQ(DetectColmapFormat(dir), format);
    EXPECT_TRUE(SameReconstruction(expected, ReadColmapModel(dir), 0));
  }
}

TEST(ColmapIo, BinaryToTextToBinaryIsByteIdentical) {
  const testing::TempDir temp;
  WriteColmapModel(RandomReconstruction(5), temp / "a", ColmapFormat::kBinary);
  WriteColmapModel(ReadColmapModel(temp / "a"), temp / "b", ColmapFormat::kText);
  WriteColmapModel(ReadColmapModel(temp / "b"), temp / "c", ColmapFormat::kBinary);
  WriteColmapModel(ReadColmapModel(temp / "c"), temp / "d", ColmapFormat::kText);
  for (const char* name : {"cameras", "images", "points3D"}) {
    EXPECT_EQ(ReadFile(temp / "a" / (std::string(name) + ".bin")),
              ReadFile(temp / "c" / (std::string(name) + ".bin")))
        << name;
    EXPECT_EQ(ReadFile(temp / "b" / (std::string(name) + ".txt")),
              ReadFile(temp / "d" / (std::string(name) + ".txt")))
        << name;
  }
}

TEST(ColmapIo, TextIsWrittenInColmapLayout) {
  Reconstruction reconstruction;
  reconstruction.cameras[1] = {1, CameraModelId::kPinhole, 640, 480, {500, 510.5, 320, 240}};
  Image image;
  image.image_id = 5;
  image.name = "a.jpg";
  image.camera_id = 1;
  image.cam_from_world.translation = Eigen::Vector3d(0.5, -2, 0.1);
  image.points2D.resize(2);
  image.points2D[0].xy = Eigen::Vector2d(10.25, 20.5);
  image.points2D[0].point3D_id = 7;
  image.points2D[1].xy = Eigen::Vector2d(30, 40);
  reconstruction.images[5] = image;
  image.image_id = 6;
  image.name = "b.jpg";
  image.points2D.clear();
  reconstruction.images[6] = image;
  reconstruction.points3D[7].xyz = Eigen::Vector3d(1, 2, 3);
  reconstruction.points3D[7].color << 255, 0, 7;
  reconstruction.points3D[7].error = 0.25;
  reconstruction.points3D[7].track = {{5, 0}};

  EXPECT_EQ(WriteToString(&WriteCamerasText, reconstruction.cameras),
            "# Camera list with one line of data per camera:\n"
            "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
            "# Number of cameras: 1\n"
            "1 PINHOLE 640 480 500 510.5 320 240\n");
  EXPECT_EQ(WriteToString(&WriteImagesText, reconstruction.images),
            "# Image list with two lines of data per image:\n"
            "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
            "#   POINTS2D[] as (X, Y, POINT3D_ID)\n"
            "# Number of images: 2, mean observations per image: 0.5\n"
            "5 1 0 0 0 0.5 -2 0.10000000000000001 1 a.jpg\n"
            "10.25 20.5 7 30 40 -1\n"
            "6 1 0 0 0 0.5 -2 0.10000000000000001 1 b.jpg\n"
            "\n");
  EXPECT_EQ(WriteToString(&WritePoints3DText, reconstruction.points3D),
            "# 3D point list with one line of data per point:\n"
            "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
            "# Number of points: 1, mean track length: 1\n"
            "7 1 2 3 255 0 7 0.25 5 0\n");
}

TEST(ColmapIo, WritersRejectNamesTheyCannotHold) {
  for (const std::string name : {"with space.jpg", "", "tab\t.jpg"}) {
    std::map<image_t, Image> images;
    images[1].image_id = 1;
    images[1].name = name;
    std::ostringstream stream;
    EXPECT_THAT(testing::InvalidArgumentMessage([&] { WriteImagesText(stream, images); }),
                HasSubstr("image 1"));
    EXPECT_TRUE(stream.str().empty());
  }
  std::map<image_t, Image> images;
  images[1].name = std::string("a\0b", 3);
  std::ostringstream stream;
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { WriteImagesBinary(stream, images); }),
              HasSubstr("NUL"));
}

TEST(ColmapIo, NonUnitQuaternionIsNormalizedAsColmapDoes) {
  const std::string text = "1 0.5 0.5 0.5 0.5000001 0 0 0 1 a.jpg\n\n";
  const auto images = ReadFromString(&ReadImagesText, text, "images.txt");
  EXPECT_NEAR(images.at(1).cam_from_world.rotation.norm(), 1, 1e-15);
  EXPECT_THAT(testing::InvalidArgumentMessage(
                  [] { ReadFromString(&ReadImagesText, "1 0 0 0 0 0 0 0 1 a.jpg\n\n", "i"); }),
              HasSubstr("quaternion"));
}

// Every proper prefix of every binary file fails, naming the file and the truncation.
TEST(ColmapIoBadInput, EveryTruncationOfABinaryFileFails) {
  const Reconstruction reconstruction = RandomReconstruction(6);
  const std::string cameras = WriteToString(&WriteCamerasBinary, reconstruction.cameras);
  const std::string images = WriteToString(&WriteImagesBinary, reconstruction.images);
  const std::string points3D = WriteToString(&WritePoints3DBinary, reconstruction.points3D);
  for (size_t size = 0; size < cameras.size(); ++size) {
    const std::string message = testing::InvalidArgumentMessage(
        [&] { ReadFromString(&ReadCamerasBinary, cameras.substr(0, size), "c.bin"); });
    ASSERT_THAT(message, HasSubstr("c.bin")) << size;
    ASSERT_THAT(message, HasSubstr("truncated")) << size;
  }
  for (size_t size = 0; size < images.size(); size += 7) {
    const std::string message = testing::InvalidArgumentMessage(
        [&] { ReadFromString(&ReadImagesBinary, images.substr(0, size), "i.bin"); });
    ASSERT_THAT(message, HasSubstr("i.bin")) << size;
    ASSERT_THAT(message, HasSubstr("truncated")) << size;
  }
  for (size_t size = 0; size < points3D.size(); size += 3) {
    const std::string message = testing::InvalidArgumentMessage(
        [&] { ReadFromString(&ReadPoints3DBinary, points3D.substr(0, size), "p.bin"); });
    ASSERT_THAT(message, HasSubstr("p.bin")) << size;
    ASSERT_THAT(message, HasSubstr("truncated")) << size;
  }
}

// A text file cut at a line boundary still parses; the header's count catches it.
TEST(ColmapIoBadInput, TextCutAtALineFailsOnTheHeaderCount) {
  const Reconstruction reconstruction = RandomReconstruction(7);
  std::string points3D = WriteToString(&WritePoints3DText, reconstruction.points3D);
  points3D.resize(points3D.rfind('\n', points3D.size() - 2) + 1);
  EXPECT_THAT(testing::InvalidArgumentMessage(
                  [&] { ReadFromString(&ReadPoints3DText, points3D, "points3D.txt"); }),
              HasSubstr("points3D.txt: the header declares 80 points3D, the file holds 79"));
}

// A stream that cannot tell its size, like a pipe.
class UnseekableBuffer : public std::streambuf {
 public:
  explicit UnseekableBuffer(std::string bytes) : bytes_(std::move(bytes)) {
    setg(bytes_.data(), bytes_.data(), bytes_.data() + bytes_.size());
  }

 private:
  std::string bytes_;
};

TEST(ColmapIoBadInput, AbsurdCountsFailWithoutAllocatingForThem) {
  const Reconstruction reconstruction = RandomReconstruction(8);
  std::string images = WriteToString(&WriteImagesBinary, reconstruction.images);
  std::string points3D = WriteToString(&WritePoints3DBinary, reconstruction.points3D);
  const uint64_t absurd = uint64_t{1} << 60;
  std::string bad_count = images;
  std::memcpy(bad_count.data(), &absurd, 8);
  EXPECT_THAT(testing::InvalidArgumentMessage(
                  [&] { ReadFromString(&ReadImagesBinary, bad_count, "images.bin"); }),
              HasSubstr("images.bin: header: 1152921504606846976 images declared"));
  // The first image has no 2D points: its count follows the header, id, pose, camera and name.
  const Image& first = reconstruction.images.begin()->second;
  ASSERT_TRUE(first.points2D.empty());
  const size_t offset = 8 + 4 + 7 * 8 + 4 + first.name.size() + 1;
  std::memcpy(images.data() + offset, &absurd, 8);
  EXPECT_THAT(testing::InvalidArgumentMessage(
                  [&] { ReadFromString(&ReadImagesBinary, images, "images.bin"); }),
              HasSubstr(fmt::format("images.bin: image {} (name '{}'): {} points2D declared",
                                    first.image_id, first.name, absurd)));
  std::memcpy(points3D.data() + 8 + 8 + 3 * 8 + 3 + 8, &absurd, 8);
  EXPECT_THAT(testing::InvalidArgumentMessage(
                  [&] { ReadFromString(&ReadPoints3DBinary, points3D, "points3D.bin"); }),
              HasSubstr("track elements declared"));
  UnseekableBuffer pipe(images);
  std::istream pipe_stream(&pipe);
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { ReadImagesBinary(pipe_stream, "pipe"); }),
              HasSubstr("pipe: image"));
}

TEST(ColmapIoBadInput, UnknownCameraModelIdFails) {
  const Reconstruction reconstruction = RandomReconstruction(9);
  std::string cameras = WriteToString(&WriteCamerasBinary, reconstruction.cameras);
  const int32_t model_id = 99;
  std::memcpy(cameras.data() + 8 + 4, &model_id, 4);
  EXPECT_THAT(testing::InvalidArgumentMessage(
                  [&] { ReadFromString(&ReadCamerasBinary, cameras, "cameras.bin"); }),
              HasSubstr(fmt::format("cameras.bin: camera {}: unknown camera model id 99",
                                    reconstruction.cameras.begin()->first)));
}

TEST(ColmapIoBadInput, BytesAfterTheLastRecordFail) {
  const Reconstruction reconstruction = RandomReconstruction(10);
  const std::string points3D = WriteToString(&WritePoints3DBinary, reconstruction.points3D);
  EXPECT_THAT(testing::InvalidArgumentMessage(
                  [&] { ReadFromString(&ReadPoints3DBinary, points3D + "xy", "p.bin"); }),
              HasSubstr("p.bin: 2 bytes of unexpected data after the 80 points3D"));
}

TEST(ColmapIoBadInput, DuplicateIdsFail) {
  std::map<camera_t, Camera> cameras;
  cameras[3] = {3, CameraModelId::kSimplePinhole, 640, 480, {500, 320, 240}};
  std::string binary = WriteToString(&WriteCamerasBinary, cameras);
  const uint64_t two = 2;
  binary =
      std::string(reinterpret_cast<const char*>(&two), 8) + binary.substr(8) + binary.substr(8);
  EXPECT_THAT(testing::InvalidArgumentMessage(
                  [&] { ReadFromString(&ReadCamerasBinary, binary, "cameras.bin"); }),
              HasSubstr("duplicate camera id 3"));
  const std::string text = "3 SIMPLE_PINHOLE 640 480 500 320 240\n3 PINHOLE 64 48 5 5 3 2\n";
  EXPECT_THAT(testing::InvalidArgumentMessage(
                  [&] { ReadFromString(&ReadCamerasText, text, "cameras.txt"); }),
              HasSubstr("cameras.txt:2: camera 3: duplicate camera id 3"));
}

TEST(ColmapIoBadInput, MalformedTextFailsNamingFileLineAndField) {
  const std::vector<std::pair<std::string, std::string>> bad_cameras = {
      {"# c\n1 PINHOLE 640 480 500 500 320\n", "cameras.txt:2: camera 1: model PINHOLE takes 4"},
      {"1 PINHOLE 640 480 500 abc 320 240\n", "cameras.txt:1: camera 1: PARAMS (field 6) 'abc'"},
      {"1 PINHOLE 640 -480 500 500 320 240\n", "HEIGHT (field 4) '-480' is not an integer"},
      {"1 NO_SUCH_MODEL 640 480 1 2 3\n", "cameras.txt:1: camera 1: "},
      {"1 PINHOLE 640\n", "found 3 fields"},
  };
  for (const auto& [text, expected] : bad_cameras) {
    EXPECT_THAT(testing::InvalidArgumentMessage(
                    [&] { ReadFromString(&ReadCamerasText, text, "cameras.txt"); }),
                HasSubstr(expected));
  }
  const std::vector<std::pair<std::string, std::string>> bad_images = {
      {"1 1 0 0 0 0 0 0 1 a.jpg\n", "images.txt:1: image 1 (name 'a.jpg'): the file ends before"},
      {"1 1 0 0 0 0 0 0 1 a.jpg\n1 2\n", "images.txt:2: image 1 (name 'a.jpg'): POINTS2D line"},
      {"1 1 0 0 0 0 0 0 1 a.jpg\n1 2 x\n", "POINTS2D POINT3D_ID (field 3) 'x'"},
      {"1 1 0 0 0 0 0 0 1 a b.jpg\n\n", "found 11 fields"},
      {"1 1 0 0 0 0 0 0 1 a.jpg\n\n1 1 0 0 0 0 0 0 1 b.jpg\n\n", "duplicate image id 1"},
  };
  for (const auto& [text, expected] : bad_images) {
    EXPECT_THAT(testing::InvalidArgumentMessage(
                    [&] { ReadFromString(&ReadImagesText, text, "images.txt"); }),
                HasSubstr(expected));
  }
  const std::vector<std::pair<std::string, std::string>> bad_points3D = {
      {"7 1 2 3 300 0 0 0.5 1 0\n", "points3D.txt:1: point3D 7: R (field 5) '300'"},
      {"7 1 2 3 0 0 0 0.5 1\n", "found 9 fields"},
      {"7 1 2 3 0 0 0 1e99999 1 0\n", "ERROR (field 8)"},
  };
  for (const auto& [text, expected] : bad_points3D) {
    EXPECT_THAT(testing::InvalidArgumentMessage(
                    [&] { ReadFromString(&ReadPoints3DText, text, "points3D.txt"); }),
                HasSubstr(expected));
  }
}

TEST(ColmapIoBadInput, MissingFilesAreNamed) {
  const testing::TempDir temp;
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { ReadColmapModel(temp / "nowhere"); }),
              HasSubstr("not a directory"));
  const std::string message =
      testing::InvalidArgumentMessage([&] { ReadColmapModel(temp.path()); });
  EXPECT_THAT(message, HasSubstr("cameras.bin, images.bin, points3D.bin"));
  EXPECT_THAT(message, HasSubstr("cameras.txt, images.txt, points3D.txt"));
  WriteColmapModel(RandomReconstruction(11), temp.path(), ColmapFormat::kBinary);
  fs::remove(temp / "images.bin");
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { ReadColmapModel(temp.path()); }),
              HasSubstr("binary lacks images.bin, text lacks cameras.txt"));
}

TEST(ColmapIoBadInput, InconsistentModelFailsNamingTheDirectory) {
  const testing::TempDir temp;
  Reconstruction reconstruction = RandomReconstruction(12);
  auto& point3D = reconstruction.points3D.begin()->second;
  point3D.track.push_back({999999, 0});
  WriteColmapModel(reconstruction, temp.path(), ColmapFormat::kBinary);
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { ReadColmapModel(temp.path()); }),
              HasSubstr(fmt::format("COLMAP model '{}': point3D {}: track names image 999999",
                                    temp.path().string(), reconstruction.points3D.begin()->first)));
}

struct RealModel {
  const char* name;
  const char* subdirectory;
  ColmapFormat format;
  size_t num_images;
  size_t num_points3D;
  size_t num_observations;  // the data set's README, from colmap model_analyzer
};

// Names the parameter in test listings (ctest shows it) instead of dumping its bytes.
void PrintTo(const RealModel& model, std::ostream* stream) { *stream << model.subdirectory; }

class ColmapIoRealData : public ::testing::TestWithParam<RealModel> {
 protected:
  // Runs COLMAP, failing the test with its output when it fails.
  static void RunColmap(const std::string& colmap, const std::string& arguments,
                        const fs::path& log) {
    const int status = testing::RunCommand(colmap + " " + arguments, log.string());
    ASSERT_EQ(status, 0) << colmap << " " << arguments << "\n" << ReadFile(log);
  }

  static void ConvertWithColmap(const std::string& colmap, const fs::path& input,
                                const fs::path& output, ColmapFormat format, const fs::path& log) {
    fs::create_directories(output);
    RunColmap(colmap,
              fmt::format("model_converter --input_path '{}' --output_path '{}' --output_type {}",
                          input.string(), output.string(),
                          format == ColmapFormat::kBinary ? "BIN" : "TXT"),
              log);
  }
};

TEST_P(ColmapIoRealData, HasTheKnownCounts) {
  HSCLOC_REQUIRE_REAL_DATA(dir, GetParam().subdirectory);
  EXPECT_EQ(DetectColmapFormat(dir), GetParam().format);
  const Reconstruction reconstruction = ReadColmapModel(dir);
  EXPECT_EQ(reconstruction.images.size(), GetParam().num_images);
  EXPECT_EQ(reconstruction.points3D.size(), GetParam().num_points3D);
  EXPECT_EQ(reconstruction.NumObservations(), GetParam().num_observations);
}

TEST_P(ColmapIoRealData, ReadsWhatColmapModelConverterWrites) {
  HSCLOC_REQUIRE_REAL_DATA(dir, GetParam().subdirectory);
  HSCLOC_REQUIRE_COLMAP(colmap);
  const testing::TempDir temp;
  const ColmapFormat other =
      GetParam().format == ColmapFormat::kBinary ? ColmapFormat::kText : ColmapFormat::kBinary;
  ConvertWithColmap(colmap, dir, temp / "converted", other, temp / "colmap.log");
  if (HasFatalFailure()) return;
  EXPECT_EQ(DetectColmapFormat(temp / "converted"), other);
  // COLMAP renormalizes quaternions and writes text with 17 digits.
  EXPECT_TRUE(SameReconstruction(ReadColmapModel(dir), ReadColmapModel(temp / "converted"), 1e-12));
}

TEST_P(ColmapIoRealData, ColmapReadsOurBinaryModel) {
  HSCLOC_REQUIRE_REAL_DATA(dir, GetParam().subdirectory);
  HSCLOC_REQUIRE_COLMAP(colmap);
  const testing::TempDir temp;
  const Reconstruction reconstruction = ReadColmapModel(dir);
  WriteColmapModel(reconstruction, temp / "ours", ColmapFormat::kBinary);
  RunColmap(colmap, fmt::format("model_analyzer --path '{}'", (temp / "ours").string()),
            temp / "analyzer.log");
  if (HasFatalFailure()) return;
  const std::string log = ReadFile(temp / "analyzer.log");
  const auto count = [&](const std::string& label) -> long {
    std::smatch match;
    if (!std::regex_search(log, match, std::regex("\\b" + label + ": ([0-9]+)"))) return -1;
    return std::stol(match[1]);
  };
  EXPECT_EQ(count("Registered images"), static_cast<long>(reconstruction.images.size())) << log;
  EXPECT_EQ(count("Points"), static_cast<long>(reconstruction.points3D.size())) << log;
  EXPECT_EQ(count("Observations"), static_cast<long>(reconstruction.NumObservations())) << log;
}

TEST_P(ColmapIoRealData, ColmapConvertsOurTextModelBack) {
  HSCLOC_REQUIRE_REAL_DATA(dir, GetParam().subdirectory);
  HSCLOC_REQUIRE_COLMAP(colmap);
  const testing::TempDir temp;
  const Reconstruction reconstruction = ReadColmapModel(dir);
  WriteColmapModel(reconstruction, temp / "ours", ColmapFormat::kText);
  ConvertWithColmap(colmap, temp / "ours", temp / "back", ColmapFormat::kBinary,
                    temp / "colmap.log");
  if (HasFatalFailure()) return;
  EXPECT_TRUE(SameReconstruction(reconstruction, ReadColmapModel(temp / "back"), 1e-12));
}

// Binary files are cut anywhere; text files at line boundaries after the header, where only its
// count can tell.
TEST_P(ColmapIoRealData, TruncatedFilesFailNamingTheFile) {
  HSCLOC_REQUIRE_REAL_DATA(dir, GetParam().subdirectory);
  const testing::TempDir temp;
  const bool binary = GetParam().format == ColmapFormat::kBinary;
  const std::string extension = binary ? ".bin" : ".txt";
  for (const char* stem : {"cameras", "images", "points3D"}) {
    const std::string name = stem + extension;
    const std::string bytes = ReadFile(dir / name);
    for (size_t size : {size_t{0}, size_t{5}, size_t{8}, size_t{45}, bytes.size() / 3,
                        bytes.size() / 2, bytes.size() - 1}) {
      if (!binary) {
        // Cut before the header's count, a file is an empty model: COLMAP's too.
        const size_t header_end = bytes.find('\n', bytes.find("# Number of")) + 1;
        size = std::max(header_end, bytes.rfind('\n', size == 0 ? 0 : size - 1) + 1);
      }
      fs::create_directories(temp / "cut");
      for (const char* other : {"cameras", "images", "points3D"}) {
        const std::string other_name = other + extension;
        WriteFile(temp / "cut" / other_name,
                  other_name == name ? bytes.substr(0, size) : ReadFile(dir / other_name));
      }
      const std::string message =
          testing::InvalidArgumentMessage([&] { ReadColmapModel(temp / "cut"); });
      EXPECT_THAT(message, HasSubstr((temp / "cut" / name).string())) << size;
      if (binary) {
        EXPECT_THAT(message, HasSubstr("truncated")) << size;
      }
    }
  }
}

INSTANTIATE_TEST_SUITE_P(
    Sets, ColmapIoRealData,
    ::testing::Values(
        RealModel{"fountain", "fountain-P11/map", ColmapFormat::kBinary, 9, 2302, 7828},
        RealModel{"lund", "lund/map", ColmapFormat::kBinary, 24, 532, 1703},
        RealModel{"maupertuis", "maupertuis/map_txt", ColmapFormat::kText, 4, 1039, 3355}),
    [](const ::testing::TestParamInfo<RealModel>& info) { return std::string(info.param.name); });

}  // namespace
}  // namespace hscloc
