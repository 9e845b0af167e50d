#include "scene/query_io.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <fstream>

#include "util/random.h"
#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;

std::filesystem::path WriteText(const testing::TempDir& dir, const std::string& text) {
  const std::filesystem::path path = dir / "list.txt";
  std::ofstream(path) << text;
  return path;
}

TEST(QueryIoTest, QueryListRoundTripsEveryCameraModel) {
  testing::TempDir dir;
  const std::vector<Camera> cameras = {
      Camera::FromModelName(0, "SIMPLE_RADIAL", 1024, 768, {995.0, 512.0, 384.0, 0.1299328499}),
      Camera::FromModelName(0, "PINHOLE", 1536, 1024, {1379.74, 1382.08, 760.345, 503.405}),
      Camera::FromModelName(0, "OPENCV", 640, 480, {500, 501, 320, 240, 0.01, -0.02, 1e-4, 2e-4})};
  std::string text = "# name model width height params\n\n";
  for (size_t i = 0; i < cameras.size(); ++i) {
    text += FormatIntrinsicsLine("query/day/" + std::to_string(i) + ".jpg", cameras[i]);
  }
  const std::vector<QueryWithIntrinsics> queries = ReadQueryList(WriteText(dir, text));
  ASSERT_EQ(queries.size(), cameras.size());
  for (size_t i = 0; i < cameras.size(); ++i) {
    EXPECT_EQ(queries[i].name, "query/day/" + std::to_string(i) + ".jpg");
    EXPECT_EQ(queries[i].camera.model_id, cameras[i].model_id);
    EXPECT_EQ(queries[i].camera.width, cameras[i].width);
    EXPECT_EQ(queries[i].camera.params, cameras[i].params);  // bit-exact
  }
}

TEST(QueryIoTest, PosesRoundTripBitExactly) {
  testing::TempDir dir;
  Random random(5);
  std::vector<NamedPose> poses;
  std::string text;
  for (int i = 0; i < 20; ++i) {
    Eigen::Quaterniond rotation(random.Normal(), random.Normal(), random.Normal(), random.Normal());
    rotation.normalize();
    poses.push_back({"img" + std::to_string(i) + ".png",
                     Rigid3d(rotation, Eigen::Vector3d(random.Normal(0, 100), random.Normal(),
                                                       random.Normal(0, 1e-3)))});
    text += FormatPoseLine(poses.back().name, poses.back().cam_from_world);
  }
  const std::vector<NamedPose> read = ReadPoses(WriteText(dir, text + "\r\n"));
  ASSERT_EQ(read.size(), poses.size());
  for (size_t i = 0; i < poses.size(); ++i) {
    EXPECT_EQ(read[i].name, poses[i].name);
    EXPECT_EQ(read[i].cam_from_world.translation, poses[i].cam_from_world.translation);
    EXPECT_NEAR(read[i].cam_from_world.rotation.angularDistance(poses[i].cam_from_world.rotation),
                0, 1e-12);
  }
}

TEST(QueryIoTest, MalformedLinesNameFileAndLine) {
  testing::TempDir dir;
  const auto query_error = [&](const std::string& text) {
    return testing::InvalidArgumentMessage([&] { ReadQueryList(WriteText(dir, text)); });
  };
  EXPECT_THAT(query_error("a.jpg PINHOLE 10 10 1 1 5\n"), HasSubstr("list.txt:1"));
  EXPECT_THAT(query_error("a.jpg PINHOLE 10 10 1 1 5 5\n# c\nb.jpg FANCY 10 10 1\n"),
              HasSubstr("list.txt:3"));
  EXPECT_THAT(query_error("a.jpg PINHOLE 10 10 1 1 5 x5\n"), HasSubstr("'x5'"));
  EXPECT_THAT(query_error("a.jpg PINHOLE 10 10 1 1 5 5\na.jpg PINHOLE 10 10 1 1 5 5\n"),
              HasSubstr("twice"));
  EXPECT_THAT(query_error("a.jpg PINHOLE ten 10 1 1 5 5\n"), HasSubstr("expected NAME MODEL"));

  const auto pose_error = [&](const std::string& text) {
    return testing::InvalidArgumentMessage([&] { ReadPoses(WriteText(dir, text)); });
  };
  EXPECT_THAT(pose_error("a.jpg 1 0 0 0 1 2\n"), HasSubstr("expected NAME QW"));
  EXPECT_THAT(pose_error("a.jpg 2 0 0 0 1 2 3\n"), HasSubstr("unit quaternion"));
  EXPECT_THAT(pose_error("a.jpg 1 0 0 0 1 2 nan\n"), HasSubstr("list.txt:1"));
  EXPECT_THAT(pose_error("a.jpg 1 0 0 0 1 2 3 4\n"), HasSubstr("unexpected '4'"));
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { ReadPoses(dir / "missing.txt"); }),
              HasSubstr("cannot read"));
}

TEST(QueryIoTest, BasenameDropsDirectories) {
  EXPECT_EQ(ImageBasename("query/night/nexus5x/IMG_1.jpg"), "IMG_1.jpg");
  EXPECT_EQ(ImageBasename("IMG_1.jpg"), "IMG_1.jpg");
}

}  // namespace
}  // namespace hscloc
