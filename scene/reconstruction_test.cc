#include "scene/reconstruction.h"

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <string>

namespace hscloc {
namespace {

using ::testing::HasSubstr;

// Two images of one camera: point3D 10 seen by both, point3D 11 by the second only.
Reconstruction SmallReconstruction() {
  Reconstruction reconstruction;
  reconstruction.cameras[1] = {1, CameraModelId::kSimplePinhole, 640, 480, {500, 320, 240}};
  for (const image_t image_id : {1, 2}) {
    Image& image = reconstruction.images[image_id];
    image.image_id = image_id;
    image.name = fmt::format("{}.jpg", image_id);
    image.camera_id = 1;
    image.points2D.resize(3);
  }
  reconstruction.images[1].points2D[0].point3D_id = 10;
  reconstruction.images[2].points2D[2].point3D_id = 10;
  reconstruction.images[2].points2D[1].point3D_id = 11;
  reconstruction.points3D[10].track = {{1, 0}, {2, 2}};
  reconstruction.points3D[11].track = {{2, 1}};
  return reconstruction;
}

std::string CheckError(const Reconstruction& reconstruction) {
  try {
    reconstruction.Check();
  } catch (const std::invalid_argument& error) {
    return error.what();
  }
  return "Check() passed";
}

TEST(Reconstruction, ConsistentReconstructionPasses) {
  EXPECT_NO_THROW(Reconstruction().Check());
  const Reconstruction reconstruction = SmallReconstruction();
  EXPECT_NO_THROW(reconstruction.Check());
  EXPECT_EQ(reconstruction.NumObservations(), 3u);
}

TEST(Reconstruction, MissingOrInvalidCameraIsNamed) {
  Reconstruction reconstruction = SmallReconstruction();
  reconstruction.images[2].camera_id = 7;
  EXPECT_THAT(CheckError(reconstruction), HasSubstr("image 2 (name '2.jpg'): camera 7 does not"));
  reconstruction = SmallReconstruction();
  reconstruction.cameras[1].params[0] = -1;
  EXPECT_THAT(CheckError(reconstruction), HasSubstr("camera 1"));
  reconstruction = SmallReconstruction();
  reconstruction.cameras[1].camera_id = 4;
  EXPECT_THAT(CheckError(reconstruction), HasSubstr("camera 4 is stored under id 1"));
}

TEST(Reconstruction, TrackNamingAMissingImageFails) {
  Reconstruction reconstruction = SmallReconstruction();
  reconstruction.points3D[10].track.push_back({5, 0});
  EXPECT_THAT(CheckError(reconstruction),
              HasSubstr("point3D 10: track names image 5, which does not exist"));
}

TEST(Reconstruction, TrackIndexOutOfRangeFails) {
  Reconstruction reconstruction = SmallReconstruction();
  reconstruction.points3D[10].track.push_back({1, 3});
  EXPECT_THAT(CheckError(reconstruction),
              HasSubstr("point3D 10: track names 2D point 3 of image 1, which has 3"));
}

TEST(Reconstruction, TrackNamingAPoint2DOfAnotherPointFails) {
  Reconstruction reconstruction = SmallReconstruction();
  reconstruction.points3D[11].track.push_back({1, 1});
  EXPECT_THAT(CheckError(reconstruction),
              HasSubstr("point3D 11: track names 2D point 1 of image 1, whose point3D_id is none"));
  reconstruction = SmallReconstruction();
  reconstruction.points3D[11].track.push_back({1, 0});
  EXPECT_THAT(CheckError(reconstruction), HasSubstr("whose point3D_id is 10"));
}

TEST(Reconstruction, DuplicateTrackElementFails) {
  Reconstruction reconstruction = SmallReconstruction();
  reconstruction.points3D[10].track.push_back({1, 0});
  EXPECT_THAT(CheckError(reconstruction),
              HasSubstr("point3D 10: track names 2D point 0 of image 1 twice"));
}

TEST(Reconstruction, Point2DMissingFromItsTrackFails) {
  Reconstruction reconstruction = SmallReconstruction();
  reconstruction.points3D[10].track = {{1, 0}};
  EXPECT_THAT(CheckError(reconstruction),
              HasSubstr("image 2 (name '2.jpg'): 2D point 2 names point3D 10, whose track does "
                        "not contain it"));
}

TEST(Reconstruction, Point2DNamingAMissingPointFails) {
  Reconstruction reconstruction = SmallReconstruction();
  reconstruction.images[1].points2D[1].point3D_id = 99;
  EXPECT_THAT(CheckError(reconstruction),
              HasSubstr("image 1 (name '1.jpg'): 2D point 1 names point3D 99, which does not"));
}

}  // namespace
}  // namespace hscloc
