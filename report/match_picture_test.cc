#include "report/match_picture.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "report/html_test_support.h"

namespace hscloc {
namespace {

using testing::CountOf;
using ::testing::HasSubstr;

TEST(MatchPictureTest, TwoMarkersPerMatchInFrontOfTheCamera) {
  Scene scene;
  scene.cameras[1] = Camera::FromModelName(1, "SIMPLE_PINHOLE", 400, 300, {300, 200, 150});
  scene.images.resize(1);
  scene.images[0].camera_id = 1;
  scene.images[0].name = "db<0>.jpg";
  // The fourth point is behind the camera, the fifth outside its image (a pooled match).
  scene.points = {{0, 0, 5}, {1, 0, 5}, {0, 1, 5}, {0, 0, -5}, {20, 0, 5}};
  LocalizationQuery query;
  query.name = "query.jpg";
  query.camera = scene.cameras[1];
  query.keypoints.resize(5, 2);
  query.keypoints << 10, 10, 20, 20, 30, 30, 40, 40, 50, 50;
  PoseResult result;
  result.success = true;
  result.best_candidate = 0;
  result.candidates.resize(1);
  result.num_inliers = 3;
  result.num_pooled_candidates = 2;
  result.match_keypoints = {0, 1, 2, 3, 4};
  result.match_points = {0, 1, 2, 3, 4};
  result.match_inliers = {1, 1, 0, 1, 1};
  const std::string svg = MatchPictureSvg(query, result, scene);
  EXPECT_EQ(testing::UnbalancedTag(svg), "");
  EXPECT_EQ(CountOf(svg, "class='inlier'"), 4u);  // two inliers in the image, twice each
  EXPECT_EQ(CountOf(svg, "class='outlier'"), 2u);
  EXPECT_THAT(svg, HasSubstr("3 inliers (green) of 5 matches from 2 retrieved image(s), shown in "
                             "db&lt;0&gt;.jpg"));
  // No photos given: grey frames.
  EXPECT_EQ(CountOf(svg, "<image"), 0u);
  EXPECT_EQ(CountOf(svg, "fill='#dde'"), 2u);

  result.success = false;
  EXPECT_EQ(MatchPictureSvg(query, result, scene), "");
}

}  // namespace
}  // namespace hscloc
