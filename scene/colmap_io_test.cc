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

#include "scene/colmap_io_test_support.h"
#include "util/testing.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;
using namespace colmap_io_testing;

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

}  // namespace
}  // namespace hscloc
