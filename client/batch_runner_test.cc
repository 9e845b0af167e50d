#include "client/batch_runner.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <map>

#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;

// Features held in memory, for batches that never reach a server.
class MemoryFeatures : public FeatureReader {
 public:
  explicit MemoryFeatures(std::map<std::string, ImageFeatures> images)
      : images_(std::move(images)) {}
  std::vector<std::string> ImageNames() const override {
    std::vector<std::string> names;
    for (const auto& [name, features] : images_) names.push_back(name);
    return names;
  }
  bool HasImage(const std::string& name) const override { return images_.count(name) > 0; }
  ImageFeatures Read(const std::string& name) const override { return images_.at(name); }
  const std::filesystem::path& path() const override { return path_; }

 private:
  std::map<std::string, ImageFeatures> images_;
  std::filesystem::path path_ = "memory";
};

ImageFeatures SomeFeatures() {
  ImageFeatures features;
  features.keypoints = KeypointMatrix::Constant(5, 2, 10.5f);
  features.descriptors = DescriptorMatrix::Constant(5, 8, 0.25f);
  return features;
}

QueryWithIntrinsics SomeQuery(const std::string& name) {
  return {name, Camera::FromModelName(1, "SIMPLE_RADIAL", 640, 480,
                                      {500.123456789012345, 320.5, 240.25, -0.0123456789})};
}

TEST(BatchRunner, CameraReachesTheWireWithFullPrecision) {
  const Camera camera = SomeQuery("q").camera;
  const wire::Camera wire_camera = CameraToWire(camera);
  EXPECT_EQ(wire_camera.model(), "SIMPLE_RADIAL");
  EXPECT_EQ(wire_camera.width(), 640u);
  ASSERT_EQ(wire_camera.params_size(), 4);
  for (int i = 0; i < 4; ++i) EXPECT_EQ(wire_camera.params(i), camera.params[i]) << i;
}

TEST(BatchRunner, PoseFromWireKeepsTheQuaternionAsSent) {
  wire::Pose pose;
  // Off unit norm in the last bits, as a server's double arithmetic may leave it.
  pose.set_qw(0.7071067811865476);
  pose.set_qx(0.7071067811865475);
  pose.set_tz(3.5);
  const Rigid3d cam_from_world = PoseFromWire(pose);
  EXPECT_EQ(cam_from_world.rotation.w(), pose.qw());
  EXPECT_EQ(cam_from_world.rotation.x(), pose.qx());
  EXPECT_EQ(cam_from_world.translation.z(), 3.5);
}

TEST(BatchRunner, BadOptionsAndMissingFeaturesAreRefusedBeforeSending) {
  testing::TempDir temp;
  const MemoryFeatures features({{"a.jpg", SomeFeatures()}});
  BatchOptions options;
  EXPECT_THROW(RunBatch({SomeQuery("a.jpg")}, features, options), std::invalid_argument);
  options.out = temp.path() / "out.txt";
  options.inflight = 0;
  EXPECT_THROW(RunBatch({SomeQuery("a.jpg")}, features, options), std::invalid_argument);
  options.inflight = 2;
  try {
    RunBatch({SomeQuery("a.jpg"), SomeQuery("missing.jpg")}, features, options);
    FAIL() << "no exception";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("missing.jpg"));
  }
}

TEST(BatchRunner, NoServerIsAClientErrorAfterTheRetries) {
  testing::TempDir temp;
  const MemoryFeatures features({{"a.jpg", SomeFeatures()}});
  BatchOptions options;
  options.out = temp.path() / "out.txt";
  options.inflight = 1;
  options.show_progress = false;
  // Nothing listens there: every attempt times out.
  options.client.servers = {"tcp://127.0.0.1:1"};
  options.client.timeout_ms = 50;
  options.client.retries = 1;
  EXPECT_THROW(RunBatch({SomeQuery("a.jpg")}, features, options), ClientError);
}

}  // namespace
}  // namespace hscloc
