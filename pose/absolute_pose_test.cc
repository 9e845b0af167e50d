#include "pose/absolute_pose.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <thread>
#include <utility>

#include "util/random.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;
using Solver = AbsolutePoseOptions::Solver;

MATCHER_P3(PoseNear, expected, max_position_error_m, max_rotation_error_deg, "") {
  const double position_error = PositionError(arg, expected);
  const double rotation_error = RotationErrorDeg(arg, expected);
  *result_listener << "camera centre off by " << position_error << " m (at most "
                   << max_position_error_m << "), rotation off by " << rotation_error
                   << " deg (at most " << max_rotation_error_deg << ")";
  return position_error <= max_position_error_m && rotation_error <= max_rotation_error_deg;
}

// A random camera of the model with moderate distortion that CamFromImg inverts on the whole
// image.
Camera RandomCamera(const std::string& model_name, Random& random) {
  const double f = random.Uniform(800, 1400);
  const double fy = f * random.Uniform(0.97, 1.03);
  const double cx = 512 + random.Uniform(-20, 20);
  const double cy = 384 + random.Uniform(-20, 20);
  std::vector<double> params;
  if (model_name == "SIMPLE_PINHOLE") {
    params = {f, cx, cy};
  } else if (model_name == "PINHOLE") {
    params = {f, fy, cx, cy};
  } else if (model_name == "SIMPLE_RADIAL") {
    params = {f, cx, cy, random.Uniform(-0.15, 0.15)};
  } else if (model_name == "RADIAL") {
    params = {f, cx, cy, random.Uniform(-0.1, 0.1), random.Uniform(0.0, 0.02)};
  } else if (model_name == "OPENCV") {
    params = {f,
              fy,
              cx,
              cy,
              random.Uniform(-0.15, 0.1),
              random.Uniform(0.0, 0.03),
              random.Uniform(-1e-3, 1e-3),
              random.Uniform(-1e-3, 1e-3)};
  } else if (model_name == "OPENCV_FISHEYE") {
    params = {f / 2, fy / 2, cx, cy, random.Uniform(-0.05, 0.05), random.Uniform(-0.01, 0.01),
              0.0,   0.0};
  }
  return Camera::FromModelName(1, model_name, 1024, 768, params);
}

struct Correspondences {
  Camera camera;
  Rigid3d cam_from_world;
  std::vector<Eigen::Vector2d> keypoints_px;
  std::vector<Eigen::Vector3d> points_in_world;
};

// Inliers: a point 2 to 30 m away along the ray of a random pixel, its keypoint that pixel plus
// Gaussian noise. Outliers are wrong matches: a keypoint paired with the point of another pixel.
Correspondences MakeCorrespondences(const Camera& camera, int num_inliers, int num_outliers,
                                    double noise_px, Random& random) {
  Correspondences data;
  data.camera = camera;
  data.cam_from_world =
      Rigid3d(Eigen::Quaterniond(random.Normal(), random.Normal(), random.Normal(), random.Normal())
                  .normalized(),
              Eigen::Vector3d(random.Normal(0, 20), random.Normal(0, 20), random.Normal(0, 20)));
  const Rigid3d world_from_cam = data.cam_from_world.Inverse();
  auto random_ray = [&](Eigen::Vector2d* pixel) {
    while (true) {
      *pixel = Eigen::Vector2d(random.Uniform(0, camera.width), random.Uniform(0, camera.height));
      const Eigen::Vector2d normalized = camera.CamFromImg(*pixel);
      if (normalized.allFinite()) return normalized;
    }
  };
  for (int i = 0; i < num_inliers + num_outliers; ++i) {
    Eigen::Vector2d pixel;
    const Eigen::Vector2d normalized = random_ray(&pixel);
    data.points_in_world.push_back(world_from_cam *
                                   (random.Uniform(2, 30) * normalized.homogeneous()));
    if (i < num_inliers) {
      data.keypoints_px.push_back(pixel +
                                  noise_px * Eigen::Vector2d(random.Normal(), random.Normal()));
    } else {
      random_ray(&pixel);
      data.keypoints_px.push_back(pixel);
    }
  }
  for (int i = static_cast<int>(data.keypoints_px.size()) - 1; i > 0; --i) {
    const int j = static_cast<int>(random.UniformInt(i + 1));
    std::swap(data.keypoints_px[i], data.keypoints_px[j]);
    std::swap(data.points_in_world[i], data.points_in_world[j]);
  }
  return data;
}

AbsolutePoseResult Estimate(const Correspondences& data, const AbsolutePoseOptions& options) {
  return EstimateAbsolutePose(data.camera, data.keypoints_px, data.points_in_world, options);
}

AbsolutePoseOptions OptionsFor(Solver solver) {
  AbsolutePoseOptions options;
  options.solver = solver;
  return options;
}

std::string SolverName(Solver solver) {
  return solver == Solver::kLoRansac ? "LO-RANSAC" : "OpenCV USAC";
}

struct AccuracyCase {
  double noise_px;
  double outlier_ratio;
  double max_position_error_m;
  double max_rotation_error_deg;
};

class AbsolutePoseModelTest : public ::testing::TestWithParam<std::string> {};

TEST_P(AbsolutePoseModelTest, RecoversKnownPosesUnderNoiseAndOutliers) {
  // Without noise and outliers the pose is exact. A wrong match that lands within the threshold
  // by chance (1 in 2500 here) keeps a few percent of its weight under the Cauchy loss, so with
  // outliers even noise-free data gives a pose off by up to 0.1 mm.
  const AccuracyCase cases[] = {{0.0, 0.0, 1e-6, 1e-5}, {0.0, 0.5, 1e-3, 1e-2},
                                {0.5, 0.5, 0.01, 0.05}, {1.0, 0.8, 0.02, 0.1},
                                {2.0, 0.0, 0.02, 0.1},  {2.0, 0.8, 0.05, 0.25}};
  uint64_t seed = 100;
  for (const char c : GetParam()) seed = seed * 31 + c;
  Random random(seed);
  for (const Solver solver : {Solver::kLoRansac, Solver::kOpenCvUsac}) {
    for (const AccuracyCase& test_case : cases) {
      const Camera camera = RandomCamera(GetParam(), random);
      const int num_inliers = 200;
      const int num_outliers =
          static_cast<int>(num_inliers * test_case.outlier_ratio / (1.0 - test_case.outlier_ratio));
      const Correspondences data =
          MakeCorrespondences(camera, num_inliers, num_outliers, test_case.noise_px, random);
      const AbsolutePoseResult result = Estimate(data, OptionsFor(solver));
      const std::string label = SolverName(solver) + ", noise " +
                                std::to_string(test_case.noise_px) + " px, outliers " +
                                std::to_string(test_case.outlier_ratio);
      ASSERT_TRUE(result.success) << label << ": " << result.failure_reason;
      EXPECT_THAT(result.cam_from_world,
                  PoseNear(data.cam_from_world, test_case.max_position_error_m,
                           test_case.max_rotation_error_deg))
          << label;
      EXPECT_GE(result.num_inliers, num_inliers * 9 / 10) << label;
      EXPECT_LE(result.num_inliers, num_inliers + num_outliers / 50) << label;
      EXPECT_EQ(std::count(result.inlier_mask.begin(), result.inlier_mask.end(), 1),
                result.num_inliers)
          << label;
    }
  }
}

INSTANTIATE_TEST_SUITE_P(CameraModels, AbsolutePoseModelTest,
                         ::testing::Values("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL",
                                           "OPENCV", "OPENCV_FISHEYE"),
                         [](const auto& info) { return info.param; });

// The paper's hardest regime: 100 correct matches among 1000.
TEST(AbsolutePose, SucceedsWithNinetyPercentOutliers) {
  Random random(7);
  for (const Solver solver : {Solver::kLoRansac, Solver::kOpenCvUsac}) {
    for (const char* model : {"SIMPLE_RADIAL", "OPENCV"}) {
      const Correspondences data =
          MakeCorrespondences(RandomCamera(model, random), 100, 900, 1.0, random);
      const AbsolutePoseResult result = Estimate(data, OptionsFor(solver));
      ASSERT_TRUE(result.success) << SolverName(solver) << ", " << model << ": "
                                  << result.failure_reason;
      EXPECT_THAT(result.cam_from_world, PoseNear(data.cam_from_world, 0.05, 0.25))
          << SolverName(solver) << ", " << model;
      EXPECT_GE(result.num_inliers, 90) << SolverName(solver) << ", " << model;
    }
  }
}

TEST(AbsolutePose, EarlyStopEndsSamplingWhenInliersArePlentiful) {
  Random random(8);
  const Correspondences data =
      MakeCorrespondences(RandomCamera("SIMPLE_RADIAL", random), 400, 600, 1.0, random);
  AbsolutePoseOptions options;
  // Confidence 1 disables the adaptive bound, so only the early stop can end sampling.
  options.confidence = 1.0;
  const AbsolutePoseResult early = Estimate(data, options);
  ASSERT_TRUE(early.success) << early.failure_reason;
  // An all-inlier sample takes 1 / 0.4^3 = 16 draws on average.
  EXPECT_LT(early.num_iterations, 200);
  EXPECT_THAT(early.cam_from_world, PoseNear(data.cam_from_world, 0.02, 0.1));

  options.stop_sampling_past_inliers = 0;
  const AbsolutePoseResult full = Estimate(data, options);
  ASSERT_TRUE(full.success) << full.failure_reason;
  EXPECT_EQ(full.num_iterations, options.max_iterations);
}

// With a count to beat, sampling assumes at least that inlier ratio: a set that holds fewer
// inliers is given up on after the samples that would have found more, and a set that holds more
// still finds them.
TEST(AbsolutePose, InliersToBeatEndSamplingOnSetsThatCannotBeatThem) {
  Random random(16);
  const Camera camera = RandomCamera("SIMPLE_RADIAL", random);
  AbsolutePoseOptions options;
  options.stop_sampling_past_inliers = 0;
  const Correspondences weak = MakeCorrespondences(camera, 30, 570, 1.0, random);  // 5 %
  const AbsolutePoseResult alone = Estimate(weak, options);
  EXPECT_EQ(alone.num_iterations, options.max_iterations);
  options.inliers_to_beat = 150;  // a quarter of the set: 1 / 0.25^3 = 64 samples per good one
  const AbsolutePoseResult against = Estimate(weak, options);
  EXPECT_LT(against.num_iterations, 1500);
  EXPECT_LE(against.num_inliers, 150);

  const Correspondences strong = MakeCorrespondences(camera, 300, 300, 1.0, random);
  const AbsolutePoseResult beats = Estimate(strong, options);
  ASSERT_TRUE(beats.success) << beats.failure_reason;
  EXPECT_GT(beats.num_inliers, 150);
  EXPECT_THAT(beats.cam_from_world, PoseNear(strong.cam_from_world, 0.05, 0.25));
}

// The correspondences reordered so that the first `ranked_first` hold the inliers under the true
// pose but `inliers_left_behind` of them (the rest of the first are outliers), as a matcher's
// confidence ranks matches: mostly, not perfectly.
Correspondences InliersRankedFirst(const Correspondences& data, size_t ranked_first,
                                   size_t inliers_left_behind) {
  std::vector<size_t> inliers;
  std::vector<size_t> outliers;
  for (size_t i = 0; i < data.keypoints_px.size(); ++i) {
    const Eigen::Vector3d point_in_cam = data.cam_from_world * data.points_in_world[i];
    const bool inlier =
        point_in_cam.z() > 0 &&
        (data.camera.ImgFromPointInCam(point_in_cam) - data.keypoints_px[i]).norm() < 5.0;
    (inlier ? inliers : outliers).push_back(i);
  }
  const size_t inliers_first = inliers.size() - inliers_left_behind;
  std::vector<size_t> order(inliers.begin(), inliers.begin() + inliers_first);
  order.insert(order.end(), outliers.begin(), outliers.begin() + (ranked_first - inliers_first));
  order.insert(order.end(), inliers.begin() + inliers_first, inliers.end());
  order.insert(order.end(), outliers.begin() + (ranked_first - inliers_first), outliers.end());
  Correspondences ranked = data;
  for (size_t i = 0; i < order.size(); ++i) {
    ranked.keypoints_px[i] = data.keypoints_px[order[i]];
    ranked.points_in_world[i] = data.points_in_world[order[i]];
  }
  return ranked;
}

// PROSAC: where the first correspondences hold most inliers, a pose comes within a fraction of
// the samples that uniform sampling draws (15 % inliers: about 300 samples per all-inlier one).
TEST(AbsolutePose, ProgressiveSamplingFindsRankedInliersFirst) {
  Random random(17);
  const Correspondences data =
      MakeCorrespondences(RandomCamera("SIMPLE_RADIAL", random), 90, 510, 1.0, random);
  const Correspondences ranked = InliersRankedFirst(data, 120, 10);
  AbsolutePoseOptions options;
  options.stop_sampling_past_inliers = 60;
  int uniform_samples = 0;
  int progressive_samples = 0;
  for (uint64_t seed = 0; seed < 10; ++seed) {
    options.seed = seed;
    options.progressive_sampling = false;
    uniform_samples += Estimate(ranked, options).num_iterations;
    options.progressive_sampling = true;
    const AbsolutePoseResult progressive = Estimate(ranked, options);
    ASSERT_TRUE(progressive.success) << progressive.failure_reason;
    EXPECT_THAT(progressive.cam_from_world, PoseNear(data.cam_from_world, 0.05, 0.25));
    EXPECT_GE(progressive.num_inliers, 85);
    progressive_samples += progressive.num_iterations;
  }
  EXPECT_LT(progressive_samples * 4, uniform_samples);
}

// A ranking that says nothing costs PROSAC little: ninety per cent outliers in random order.
TEST(AbsolutePose, ProgressiveSamplingSucceedsOnAnUninformativeRanking) {
  Random random(18);
  for (const char* model : {"SIMPLE_RADIAL", "OPENCV"}) {
    const Correspondences data =
        MakeCorrespondences(RandomCamera(model, random), 100, 900, 1.0, random);
    AbsolutePoseOptions options;
    options.progressive_sampling = true;
    const AbsolutePoseResult result = Estimate(data, options);
    ASSERT_TRUE(result.success) << model << ": " << result.failure_reason;
    EXPECT_THAT(result.cam_from_world, PoseNear(data.cam_from_world, 0.05, 0.25)) << model;
    EXPECT_GE(result.num_inliers, 90) << model;
  }
}

TEST(AbsolutePose, AdaptiveBoundEndsSamplingWithoutOutliers) {
  Random random(9);
  const Correspondences data =
      MakeCorrespondences(RandomCamera("PINHOLE", random), 50, 0, 0.5, random);
  AbsolutePoseOptions options;
  options.stop_sampling_past_inliers = 0;
  const AbsolutePoseResult result = Estimate(data, options);
  ASSERT_TRUE(result.success) << result.failure_reason;
  EXPECT_LT(result.num_iterations, 20);
}

double Mean(const std::vector<double>& values) {
  double sum = 0.0;
  for (const double value : values) sum += value;
  return sum / values.size();
}

// The minimal-solver pose fits three noisy points exactly; refitting all inliers averages the
// noise out.
TEST(AbsolutePose, RefinementImprovesOnTheMinimalSolverPose) {
  Random random(10);
  AbsolutePoseOptions minimal_options;
  minimal_options.local_optimization = false;
  minimal_options.refine = false;
  AbsolutePoseOptions refined_options = minimal_options;
  refined_options.refine = true;
  std::vector<double> minimal_rotation, minimal_position, refined_rotation, refined_position;
  for (int trial = 0; trial < 20; ++trial) {
    const Correspondences data =
        MakeCorrespondences(RandomCamera("OPENCV", random), 150, 150, 2.0, random);
    const AbsolutePoseResult minimal = Estimate(data, minimal_options);
    const AbsolutePoseResult refined = Estimate(data, refined_options);
    ASSERT_TRUE(minimal.success) << minimal.failure_reason;
    ASSERT_TRUE(refined.success) << refined.failure_reason;
    EXPECT_FALSE(minimal.refined);
    EXPECT_TRUE(refined.refined);
    minimal_rotation.push_back(RotationErrorDeg(minimal.cam_from_world, data.cam_from_world));
    minimal_position.push_back(PositionError(minimal.cam_from_world, data.cam_from_world));
    refined_rotation.push_back(RotationErrorDeg(refined.cam_from_world, data.cam_from_world));
    refined_position.push_back(PositionError(refined.cam_from_world, data.cam_from_world));
  }
  EXPECT_LT(Mean(refined_rotation), 0.25 * Mean(minimal_rotation));
  EXPECT_LT(Mean(refined_position), 0.25 * Mean(minimal_position));
}

// From a pose a few pixels off (0.2 deg and 5 cm from the truth), the refinement alone recovers the
// truth as RANSAC and refinement do; from a pose that sees none of the matches it fails.
TEST(AbsolutePose, RefinesFromAGivenPose) {
  Random random(12);
  for (const char* model : {"SIMPLE_RADIAL", "OPENCV"}) {
    for (int trial = 0; trial < 10; ++trial) {
      const Correspondences data =
          MakeCorrespondences(RandomCamera(model, random), 150, 100, 1.0, random);
      const Eigen::Vector3d axis =
          Eigen::Vector3d(random.Normal(), random.Normal(), random.Normal()).normalized();
      const Rigid3d start(data.cam_from_world.rotation *
                              Eigen::Quaterniond(Eigen::AngleAxisd(0.2 * M_PI / 180, axis)),
                          data.cam_from_world.translation + 0.05 * axis);
      const AbsolutePoseResult refined = RefineAbsolutePoseFrom(
          data.camera, data.keypoints_px, data.points_in_world, start, AbsolutePoseOptions());
      const AbsolutePoseResult estimated = Estimate(data, AbsolutePoseOptions());
      ASSERT_TRUE(refined.success) << model << ": " << refined.failure_reason;
      ASSERT_TRUE(estimated.success) << model << ": " << estimated.failure_reason;
      EXPECT_TRUE(refined.refined);
      EXPECT_EQ(refined.num_iterations, 0);
      EXPECT_THAT(refined.cam_from_world, PoseNear(data.cam_from_world, 0.02, 0.1)) << model;
      // Both stop where Ceres deems the cost flat, a few millimetres apart.
      EXPECT_THAT(refined.cam_from_world, PoseNear(estimated.cam_from_world, 0.005, 0.02)) << model;
      EXPECT_NEAR(refined.num_inliers, estimated.num_inliers, 2) << model;
      EXPECT_EQ(std::count(refined.inlier_mask.begin(), refined.inlier_mask.end(), 1),
                refined.num_inliers);
    }
  }
  const Correspondences data =
      MakeCorrespondences(RandomCamera("PINHOLE", random), 150, 0, 1.0, random);
  const AbsolutePoseResult lost =
      RefineAbsolutePoseFrom(data.camera, data.keypoints_px, data.points_in_world,
                             data.cam_from_world.Inverse(), AbsolutePoseOptions());
  EXPECT_FALSE(lost.success);
  EXPECT_THAT(lost.failure_reason, HasSubstr("fewer than min_inliers"));
  EXPECT_EQ(lost.inlier_mask.size(), 150u);
  Rigid3d not_finite = data.cam_from_world;
  not_finite.translation.x() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(RefineAbsolutePoseFrom(data.camera, data.keypoints_px, data.points_in_world,
                                      not_finite, AbsolutePoseOptions()),
               std::invalid_argument);
}

TEST(AbsolutePose, FailsWithAReasonOnTooFewCorrespondences) {
  Random random(11);
  const Correspondences data =
      MakeCorrespondences(RandomCamera("PINHOLE", random), 8, 0, 0.0, random);
  const AbsolutePoseResult result = Estimate(data, AbsolutePoseOptions());
  EXPECT_FALSE(result.success);
  EXPECT_THAT(result.failure_reason, HasSubstr("fewer than min_inliers"));
  EXPECT_EQ(result.inlier_mask.size(), 8u);
}

TEST(AbsolutePose, FailsWithAReasonWhenEverythingIsAnOutlier) {
  Random random(12);
  for (const Solver solver : {Solver::kLoRansac, Solver::kOpenCvUsac}) {
    const Correspondences data =
        MakeCorrespondences(RandomCamera("SIMPLE_RADIAL", random), 0, 300, 0.0, random);
    const AbsolutePoseResult result = Estimate(data, OptionsFor(solver));
    EXPECT_FALSE(result.success) << SolverName(solver);
    EXPECT_FALSE(result.failure_reason.empty()) << SolverName(solver);
  }
}

TEST(AbsolutePose, FailsWithAReasonOnDegenerateGeometry) {
  Random random(13);
  Correspondences data = MakeCorrespondences(RandomCamera("PINHOLE", random), 50, 0, 0.0, random);
  // Every 3D point on one line: no minimal sample determines a pose.
  for (size_t i = 0; i < data.points_in_world.size(); ++i) {
    data.points_in_world[i] = Eigen::Vector3d(1.0, 2.0, 3.0) * static_cast<double>(i + 1);
  }
  const AbsolutePoseResult result = Estimate(data, AbsolutePoseOptions());
  EXPECT_FALSE(result.success);
  EXPECT_THAT(result.failure_reason, HasSubstr("no hypothesis"));
}

TEST(AbsolutePose, BadInputThrowsNamingTheField) {
  Random random(14);
  Correspondences data = MakeCorrespondences(RandomCamera("PINHOLE", random), 20, 0, 0.0, random);
  const auto throws_naming = [](const std::string& field) {
    return ::testing::ThrowsMessage<std::invalid_argument>(HasSubstr(field));
  };
  Correspondences mismatched = data;
  mismatched.points_in_world.pop_back();
  EXPECT_THAT([&] { Estimate(mismatched, AbsolutePoseOptions()); },
              throws_naming("points_in_world"));
  Correspondences non_finite = data;
  non_finite.keypoints_px[3].y() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THAT([&] { Estimate(non_finite, AbsolutePoseOptions()); },
              throws_naming("keypoints_px[3]"));
  non_finite = data;
  non_finite.points_in_world[5].x() = std::numeric_limits<double>::infinity();
  EXPECT_THAT([&] { Estimate(non_finite, AbsolutePoseOptions()); },
              throws_naming("points_in_world[5]"));
  Correspondences bad_camera = data;
  bad_camera.camera.params.pop_back();
  EXPECT_THAT([&] { Estimate(bad_camera, AbsolutePoseOptions()); }, throws_naming("params"));

  const std::vector<std::pair<std::string, void (*)(AbsolutePoseOptions&)>> bad_options = {
      {"max_reprojection_error_px",
       [](AbsolutePoseOptions& o) { o.max_reprojection_error_px = 0; }},
      {"max_iterations", [](AbsolutePoseOptions& o) { o.max_iterations = 0; }},
      {"stop_sampling_past_inliers",
       [](AbsolutePoseOptions& o) { o.stop_sampling_past_inliers = -1; }},
      {"confidence", [](AbsolutePoseOptions& o) { o.confidence = 1.5; }},
      {"min_inliers", [](AbsolutePoseOptions& o) { o.min_inliers = 3; }},
      {"inliers_to_beat", [](AbsolutePoseOptions& o) { o.inliers_to_beat = -1; }},
      {"solver", [](AbsolutePoseOptions& o) { o.solver = static_cast<Solver>(7); }},
      {"loss_scale_px", [](AbsolutePoseOptions& o) { o.refinement.loss_scale_px = -1; }},
  };
  for (const auto& [field, make_bad] : bad_options) {
    AbsolutePoseOptions options;
    make_bad(options);
    EXPECT_THAT([&] { Estimate(data, options); }, throws_naming(field));
  }
}

bool SameResult(const AbsolutePoseResult& a, const AbsolutePoseResult& b) {
  return a.success == b.success && a.inlier_mask == b.inlier_mask &&
         a.num_iterations == b.num_iterations &&
         a.cam_from_world.rotation.coeffs() == b.cam_from_world.rotation.coeffs() &&
         a.cam_from_world.translation == b.cam_from_world.translation;
}

// Concurrent calls give exactly the results of sequential ones with the same seeds.
TEST(AbsolutePose, DeterministicAndThreadSafe) {
  Random random(15);
  std::vector<Correspondences> queries;
  for (int i = 0; i < 8; ++i) {
    queries.push_back(MakeCorrespondences(RandomCamera("OPENCV", random), 150, 350, 1.0, random));
  }
  for (const Solver solver : {Solver::kLoRansac, Solver::kOpenCvUsac}) {
    AbsolutePoseOptions options = OptionsFor(solver);
    options.seed = 42;
    std::vector<AbsolutePoseResult> sequential;
    for (const Correspondences& query : queries) sequential.push_back(Estimate(query, options));
    std::vector<AbsolutePoseResult> concurrent(queries.size());
    std::vector<std::thread> threads;
    for (size_t i = 0; i < queries.size(); ++i) {
      threads.emplace_back([&, i] { concurrent[i] = Estimate(queries[i], options); });
    }
    for (std::thread& thread : threads) thread.join();
    for (size_t i = 0; i < queries.size(); ++i) {
      EXPECT_TRUE(sequential[i].success) << SolverName(solver) << ", query " << i;
      EXPECT_TRUE(SameResult(sequential[i], concurrent[i]))
          << SolverName(solver) << ", query " << i;
    }
  }
}

}  // namespace
}  // namespace hscloc
