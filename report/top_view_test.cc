#include "report/top_view.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <regex>

#include "report/html_test_support.h"
#include "util/random.h"
#include "util/testing.h"

namespace hscloc {
namespace {

using testing::CountOf;
using ::testing::HasSubstr;

// An upright camera (image y down = world -z) at `center`, looking along `heading_deg` from +x.
Rigid3d UprightCamera(const Eigen::Vector3d& center, double heading_deg) {
  const double heading = heading_deg * M_PI / 180;
  const Eigen::Vector3d forward(std::cos(heading), std::sin(heading), 0);
  const Eigen::Vector3d down(0, 0, -1);
  Eigen::Matrix3d world_from_cam;
  world_from_cam << down.cross(forward), down, forward;
  return CamFromWorldFromCenter(center, world_from_cam);
}

// `pose` with its centre moved by `offset` and turned by `rotation_deg` about the vertical.
Rigid3d Moved(const Rigid3d& pose, const Eigen::Vector3d& offset, double rotation_deg = 0) {
  const Eigen::Quaterniond turn(
      Eigen::AngleAxisd(rotation_deg * M_PI / 180, Eigen::Vector3d::UnitZ()));
  const Eigen::Quaterniond rotation = pose.rotation * turn.conjugate();
  const Eigen::Vector3d center = CameraCenterInWorld(pose) + offset;
  return Rigid3d(rotation, -(rotation * center));
}

// The (x, y) of every marker of a class, in document order (circles by centre, the database
// cameras' squares by corner + 2).
std::vector<Eigen::Vector2d> Markers(const std::string& svg, const std::string& name) {
  const std::regex marker("class='" + name + "' (?:cx|x)='([-0-9.]+)' (?:cy|y)='([-0-9.]+)'");
  const double offset = name == "database-camera" ? 2 : 0;
  std::vector<Eigen::Vector2d> positions;
  for (auto it = std::sregex_iterator(svg.begin(), svg.end(), marker); it != std::sregex_iterator();
       ++it) {
    positions.emplace_back(std::stod((*it)[1]) + offset, std::stod((*it)[2]) + offset);
  }
  return positions;
}

// The endpoints (x1, y1, x2, y2) of every truth-to-estimate line.
std::vector<Eigen::Vector4d> ErrorLines(const std::string& svg) {
  const std::regex line(
      "class='query-error' x1='([-0-9.]+)' y1='([-0-9.]+)' x2='([-0-9.]+)' y2='([-0-9.]+)'");
  std::vector<Eigen::Vector4d> lines;
  for (auto it = std::sregex_iterator(svg.begin(), svg.end(), line); it != std::sregex_iterator();
       ++it) {
    lines.emplace_back(std::stod((*it)[1]), std::stod((*it)[2]), std::stod((*it)[3]),
                       std::stod((*it)[4]));
  }
  return lines;
}

// A 100 m x 50 m block: points at the corners (two heights at the south-west one), four database
// cameras along its south side, and queries: good, off by 20 m, turned by 30 deg, not localized.
TopViewContent Block() {
  TopViewContent content;
  content.points_in_world = {{0, 0, 0}, {0, 0, 12}, {100, 0, 3}, {0, 50, 3}, {100, 50, 3}};
  for (int i = 0; i < 4; ++i) {
    content.database_cams_from_world.push_back(UprightCamera({20.0 + 20 * i, 10, 1.6}, 90));
  }
  const Rigid3d truth = UprightCamera({50, 25, 1.6}, 0);
  content.queries = {{"good", truth, Moved(truth, {0.1, 0, 0})},
                     {"far", UprightCamera({30, 30, 1.6}, 45),
                      Moved(UprightCamera({30, 30, 1.6}, 45), {20, 0, 0})},
                     {"turned", UprightCamera({70, 30, 1.6}, 45),
                      Moved(UprightCamera({70, 30, 1.6}, 45), Eigen::Vector3d::Zero(), 30)},
                     {"lost", UprightCamera({60, 40, 1.6}, 0), std::nullopt}};
  return content;
}

TEST(TopViewTest, AMarkerForEveryPointCameraAndQuery) {
  const std::string svg = TopViewSvg(Block());
  EXPECT_THAT(svg, ::testing::StartsWith("<svg"));
  EXPECT_EQ(testing::UnbalancedTag(svg), "");
  EXPECT_EQ(Markers(svg, "point").size(), 5u);
  EXPECT_EQ(Markers(svg, "database-camera").size(), 4u);
  EXPECT_EQ(Markers(svg, "query-truth").size(), 4u);
  // Estimates and their lines only for the three queries that have one.
  EXPECT_EQ(Markers(svg, "query-estimate").size(), 3u);
  EXPECT_EQ(ErrorLines(svg).size(), 3u);
  // Failures: 20 m off, 30 deg turned, not localized; the good one is not marked.
  EXPECT_EQ(CountOf(svg, "class='query-failure'"), 3u);
  EXPECT_THAT(svg, HasSubstr("estimate within (5 m, 10 deg) (1)"));
  EXPECT_THAT(svg, HasSubstr("outside (5 m, 10 deg) (3)"));
  EXPECT_THAT(svg, HasSubstr("map points (5 of 5 drawn)"));
  EXPECT_THAT(svg, HasSubstr("<title>lost: not localized</title>"));
  EXPECT_EQ(CountOf(svg, "class='legend'"), 1u);
  EXPECT_EQ(CountOf(svg, "class='scale-bar'"), 1u);
}

TEST(TopViewTest, SeenFromAboveNorthUpWithOneScale) {
  const std::string svg = TopViewSvg(Block());
  const std::vector<Eigen::Vector2d> points = Markers(svg, "point");
  ASSERT_EQ(points.size(), 5u);
  // Height does not move a point; east is right, north is up (SVG y grows downwards).
  EXPECT_EQ(points[0], points[1]);
  const Eigen::Vector2d south_west = points[0], south_east = points[2], north_west = points[3];
  EXPECT_GT(south_east.x(), south_west.x());
  EXPECT_NEAR(south_east.y(), south_west.y(), 0.11);
  EXPECT_LT(north_west.y(), south_west.y());
  EXPECT_NEAR(north_west.x(), south_west.x(), 0.11);
  // 100 m east and 50 m north on one scale, the longer side filling the default 540 px.
  const double east_px = south_east.x() - south_west.x();
  const double north_px = south_west.y() - north_west.y();
  EXPECT_NEAR(east_px / north_px, 2.0, 0.01);
  EXPECT_NEAR(east_px, 540 / 1.08, 1.0);
  // The good query's truth sits at the block's centre; its line starts there.
  const Eigen::Vector2d centre = (south_west + points[4]) / 2;
  const std::vector<Eigen::Vector2d> truths = Markers(svg, "query-truth");
  EXPECT_NEAR((truths[0] - centre).norm(), 0, 0.15);
  const std::vector<Eigen::Vector4d> lines = ErrorLines(svg);
  EXPECT_NEAR((lines[0].head<2>() - truths[0]).norm(), 0, 0.15);
  EXPECT_NEAR((lines[0].tail<2>() - Markers(svg, "query-estimate")[0]).norm(), 0, 0.15);
  // The far estimate is 20 m east of its truth: 20 m of the scale.
  EXPECT_NEAR(lines[1][2] - lines[1][0], east_px / 5, 0.3);
  EXPECT_NEAR(lines[1][3] - lines[1][1], 0, 0.15);
  // Database cameras at y = 10 m, 20 m apart.
  const std::vector<Eigen::Vector2d> cameras = Markers(svg, "database-camera");
  EXPECT_NEAR(cameras[1].x() - cameras[0].x(), east_px / 5, 0.3);
  EXPECT_NEAR(south_west.y() - cameras[0].y(), north_px / 5, 0.3);
}

TEST(TopViewTest, AnSfmFrameInAnyOrientationGivesTheSameMap) {
  const TopViewContent block = Block();
  // Distances between markers, relative to the first pair's, do not depend on the world frame.
  const auto shape = [](const std::string& svg) {
    const std::vector<Eigen::Vector2d> points = Markers(svg, "point");
    const std::vector<Eigen::Vector2d> truths = Markers(svg, "query-truth");
    std::vector<double> distances;
    for (const Eigen::Vector2d& truth : truths) distances.push_back((truth - points[0]).norm());
    for (const Eigen::Vector2d& point : points) distances.push_back((point - points[0]).norm());
    const double unit = (points[2] - points[0]).norm();
    for (double& distance : distances) distance /= unit;
    return distances;
  };
  Random random(3);
  const Eigen::Quaterniond rotation =
      Eigen::Quaterniond(random.Normal(), random.Normal(), random.Normal(), random.Normal())
          .normalized();
  const Rigid3d new_from_world(rotation, Eigen::Vector3d(5, -7, 11));
  const Rigid3d world_from_new = new_from_world.Inverse();
  TopViewContent moved = block;
  for (Eigen::Vector3d& point : moved.points_in_world) point = new_from_world * point;
  for (Rigid3d& camera : moved.database_cams_from_world) camera = camera * world_from_new;
  for (TopViewQuery& query : moved.queries) {
    query.true_cam_from_world = query.true_cam_from_world * world_from_new;
    if (query.estimated_cam_from_world) {
      query.estimated_cam_from_world = *query.estimated_cam_from_world * world_from_new;
    }
  }
  const std::vector<double> expected = shape(TopViewSvg(block));
  const std::vector<double> actual = shape(TopViewSvg(moved));
  ASSERT_EQ(actual.size(), expected.size());
  for (size_t i = 0; i < expected.size(); ++i) EXPECT_NEAR(actual[i], expected[i], 0.01) << i;
}

TEST(TopViewTest, ManyPointsAreSubsampledAndFarOutliersLeftOut) {
  TopViewContent content = Block();
  content.points_in_world.clear();
  for (int i = 0; i < 1000; ++i) content.points_in_world.push_back({i * 0.1, (i % 50) * 1.0, 2});
  TopViewOptions options;
  options.max_points = 100;
  std::string svg = TopViewSvg(content, options);
  EXPECT_EQ(Markers(svg, "point").size(), 100u);
  EXPECT_THAT(svg, HasSubstr("map points (100 of 1000 drawn)"));
  // One point 10 km away does not shrink the map: it is left out.
  content.points_in_world.push_back({10000, 10000, 0});
  options.max_points = 2000;
  svg = TopViewSvg(content, options);
  EXPECT_EQ(Markers(svg, "point").size(), 1000u);
  EXPECT_THAT(svg, HasSubstr("map points (1000 of 1001 drawn)"));
}

TEST(TopViewTest, FromASceneWithEstimatesByBasename) {
  Scene scene;
  scene.points = {{0, 0, 0}, {10, 10, 0}};
  scene.images.resize(2);
  scene.images[0].cam_from_world = UprightCamera({1, 1, 1}, 0);
  scene.images[1].cam_from_world = UprightCamera({5, 5, 1}, 0);
  const std::vector<NamedPose> truth = {{"query/day/a.jpg", UprightCamera({2, 2, 1}, 0)},
                                        {"query/day/b.jpg", UprightCamera({3, 3, 1}, 0)}};
  const TopViewContent content = TopViewOf(scene, truth, {{"b.jpg", truth[1].cam_from_world}});
  EXPECT_EQ(content.points_in_world.size(), 2u);
  EXPECT_EQ(content.database_cams_from_world.size(), 2u);
  ASSERT_EQ(content.queries.size(), 2u);
  EXPECT_FALSE(content.queries[0].estimated_cam_from_world.has_value());
  EXPECT_TRUE(content.queries[1].estimated_cam_from_world.has_value());
  EXPECT_THAT(testing::InvalidArgumentMessage([&] {
                TopViewOf(scene, truth, {{"c.jpg", {}}});
              }),
              HasSubstr("'c.jpg'"));
}

TEST(TopViewTest, NamesAreEscapedAndOptionsChecked) {
  TopViewContent content = Block();
  content.queries[0].name = "a<b>";
  TopViewOptions options;
  options.title = "map & queries";
  const std::string svg = TopViewSvg(content, options);
  EXPECT_THAT(svg, HasSubstr("<title>a&lt;b&gt;: "));
  EXPECT_THAT(svg, HasSubstr(">map &amp; queries<"));
  options.max_points = 0;
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { TopViewSvg(content, options); }),
              HasSubstr("max_points"));
  // An empty map still draws (a frame, a legend).
  EXPECT_EQ(testing::UnbalancedTag(TopViewSvg({})), "");
}

}  // namespace
}  // namespace hscloc
