#include "geometry/camera.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

namespace hscloc {
namespace {

using ::testing::HasSubstr;

constexpr std::array<CameraModelId, 11> kAllModels = {
    CameraModelId::kSimplePinhole,
    CameraModelId::kPinhole,
    CameraModelId::kSimpleRadial,
    CameraModelId::kRadial,
    CameraModelId::kOpenCV,
    CameraModelId::kOpenCVFisheye,
    CameraModelId::kFullOpenCV,
    CameraModelId::kFOV,
    CameraModelId::kSimpleRadialFisheye,
    CameraModelId::kRadialFisheye,
    CameraModelId::kThinPrismFisheye,
};

constexpr int kCamerasPerModel = 20;
constexpr int kPointsPerCamera = 200;

bool IsFisheye(CameraModelId model_id) {
  return model_id == CameraModelId::kOpenCVFisheye ||
         model_id == CameraModelId::kSimpleRadialFisheye ||
         model_id == CameraModelId::kRadialFisheye || model_id == CameraModelId::kThinPrismFisheye;
}

// Largest angle from the optical axis that the random cameras image: about 35 degrees for the
// perspective models, 63 for the fisheyes.
double MaxFieldAngle(CameraModelId model_id) { return IsFisheye(model_id) ? 1.1 : std::atan(0.7); }

double Uniform(std::mt19937& rng, double low, double high) {
  return std::uniform_real_distribution<double>(low, high)(rng);
}

double Symmetric(std::mt19937& rng, double bound) { return Uniform(rng, -bound, bound); }

// Distortion of the size real lenses show, small enough that no fold lies inside the image.
std::vector<double> RandomDistortion(CameraModelId model_id, std::mt19937& rng) {
  switch (model_id) {
    case CameraModelId::kSimpleRadial:
      return {Symmetric(rng, 0.15)};
    case CameraModelId::kRadial:
      return {Symmetric(rng, 0.15), Symmetric(rng, 0.03)};
    case CameraModelId::kOpenCV:
      return {Symmetric(rng, 0.15), Symmetric(rng, 0.03), Symmetric(rng, 0.002),
              Symmetric(rng, 0.002)};
    case CameraModelId::kFullOpenCV:
      return {Symmetric(rng, 0.15),  Symmetric(rng, 0.03),  Symmetric(rng, 0.002),
              Symmetric(rng, 0.002), Symmetric(rng, 0.005), Symmetric(rng, 0.05),
              Symmetric(rng, 0.01),  Symmetric(rng, 0.002)};
    case CameraModelId::kFOV:
      return {Uniform(rng, 0.3, 1.2)};
    case CameraModelId::kSimpleRadialFisheye:
      return {Symmetric(rng, 0.05)};
    case CameraModelId::kRadialFisheye:
      return {Symmetric(rng, 0.05), Symmetric(rng, 0.01)};
    case CameraModelId::kOpenCVFisheye:
      return {Symmetric(rng, 0.05), Symmetric(rng, 0.01), Symmetric(rng, 0.002),
              Symmetric(rng, 0.0005)};
    case CameraModelId::kThinPrismFisheye:
      return {Symmetric(rng, 0.05),  Symmetric(rng, 0.01),  Symmetric(rng, 0.002),
              Symmetric(rng, 0.002), Symmetric(rng, 0.002), Symmetric(rng, 0.0005),
              Symmetric(rng, 0.002), Symmetric(rng, 0.002)};
    default:
      return {};
  }
}

// Focal length 300..2000 px, principal point near the centre, and an image whose corners lie
// somewhat inside MaxFieldAngle.
Camera RandomCamera(CameraModelId model_id, std::mt19937& rng) {
  const std::vector<double> distortion = RandomDistortion(model_id, rng);
  const bool single_focal = CameraModelNumParams(model_id) - distortion.size() == 3;
  const double focal = Uniform(rng, 300.0, 2000.0);
  const double half_diagonal = focal * (IsFisheye(model_id) ? 0.9 : 0.7);
  Camera camera;
  camera.camera_id = 1;
  camera.model_id = model_id;
  camera.width = static_cast<uint64_t>(1.6 * half_diagonal);
  camera.height = static_cast<uint64_t>(1.2 * half_diagonal);
  const double cx = 0.5 * camera.width + Symmetric(rng, 0.02 * camera.width);
  const double cy = 0.5 * camera.height + Symmetric(rng, 0.02 * camera.height);
  camera.params = single_focal
                      ? std::vector<double>{focal, cx, cy}
                      : std::vector<double>{focal, focal * Uniform(rng, 0.95, 1.05), cx, cy};
  camera.params.insert(camera.params.end(), distortion.begin(), distortion.end());
  camera.Check();
  return camera;
}

// Normalized coordinates of a ray at most max_angle from the optical axis.
Eigen::Vector2d RandomNormalized(double max_angle, std::mt19937& rng) {
  const double angle = Uniform(rng, 0.0, max_angle);
  const double azimuth = Uniform(rng, 0.0, 2.0 * M_PI);
  return std::tan(angle) * Eigen::Vector2d(std::cos(azimuth), std::sin(azimuth));
}

std::string Describe(const Camera& camera) {
  std::string text = CameraModelName(camera.model_id) + " params";
  for (const double param : camera.params) text += " " + std::to_string(param);
  return text;
}

::testing::AssertionResult VectorsNear(const Eigen::Vector2d& actual,
                                       const Eigen::Vector2d& expected, double tolerance) {
  const double distance = (actual - expected).norm();
  if (distance <= tolerance) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure()
         << "(" << actual.transpose() << ") is " << distance << " from (" << expected.transpose()
         << "), tolerance " << tolerance;
}

// COLMAP 3.8's WorldToImage written out term by term as in its camera_models.h, independently of
// the factored form the library uses, so that a parameter taken from the wrong slot shows.
Eigen::Vector2d ColmapImgFromCam(const Camera& camera, const Eigen::Vector2d& normalized) {
  const std::vector<double>& p = camera.params;
  const double u = normalized.x();
  const double v = normalized.y();
  const double r2 = u * u + v * v;
  const double r = std::sqrt(r2);
  const double theta = std::atan(r);
  const double t2 = theta * theta;
  switch (camera.model_id) {
    case CameraModelId::kSimplePinhole:
      return {p[0] * u + p[1], p[0] * v + p[2]};
    case CameraModelId::kPinhole:
      return {p[0] * u + p[2], p[1] * v + p[3]};
    case CameraModelId::kSimpleRadial:
      return {p[0] * (u + u * p[3] * r2) + p[1], p[0] * (v + v * p[3] * r2) + p[2]};
    case CameraModelId::kRadial: {
      const double radial = p[3] * r2 + p[4] * r2 * r2;
      return {p[0] * (u + u * radial) + p[1], p[0] * (v + v * radial) + p[2]};
    }
    case CameraModelId::kOpenCV: {
      const double radial = p[4] * r2 + p[5] * r2 * r2;
      const double du = u * radial + 2 * p[6] * u * v + p[7] * (r2 + 2 * u * u);
      const double dv = v * radial + 2 * p[7] * u * v + p[6] * (r2 + 2 * v * v);
      return {p[0] * (u + du) + p[2], p[1] * (v + dv) + p[3]};
    }
    case CameraModelId::kFullOpenCV: {
      const double r4 = r2 * r2;
      const double r6 = r4 * r2;
      const double radial =
          (1 + p[4] * r2 + p[5] * r4 + p[8] * r6) / (1 + p[9] * r2 + p[10] * r4 + p[11] * r6);
      const double du = u * radial + 2 * p[6] * u * v + p[7] * (r2 + 2 * u * u) - u;
      const double dv = v * radial + 2 * p[7] * u * v + p[6] * (r2 + 2 * v * v) - v;
      return {p[0] * (u + du) + p[2], p[1] * (v + dv) + p[3]};
    }
    case CameraModelId::kOpenCVFisheye: {
      const double theta_d =
          theta * (1 + p[4] * t2 + p[5] * t2 * t2 + p[6] * t2 * t2 * t2 + p[7] * t2 * t2 * t2 * t2);
      return {p[0] * u * theta_d / r + p[2], p[1] * v * theta_d / r + p[3]};
    }
    case CameraModelId::kSimpleRadialFisheye: {
      const double theta_d = theta * (1 + p[3] * t2);
      return {p[0] * u * theta_d / r + p[1], p[0] * v * theta_d / r + p[2]};
    }
    case CameraModelId::kRadialFisheye: {
      const double theta_d = theta * (1 + p[3] * t2 + p[4] * t2 * t2);
      return {p[0] * u * theta_d / r + p[1], p[0] * v * theta_d / r + p[2]};
    }
    case CameraModelId::kFOV: {
      const double omega = p[4];
      const double factor = std::atan(r * 2 * std::tan(omega / 2)) / (r * omega);
      return {p[0] * u * factor + p[2], p[1] * v * factor + p[3]};
    }
    case CameraModelId::kThinPrismFisheye: {
      const double uu = theta * u / r;
      const double vv = theta * v / r;
      const double s2 = uu * uu + vv * vv;
      const double radial =
          p[4] * s2 + p[5] * s2 * s2 + p[8] * s2 * s2 * s2 + p[9] * s2 * s2 * s2 * s2;
      const double du = uu * radial + 2 * p[6] * uu * vv + p[7] * (s2 + 2 * uu * uu) + p[10] * s2;
      const double dv = vv * radial + 2 * p[7] * uu * vv + p[6] * (s2 + 2 * vv * vv) + p[11] * s2;
      return {p[0] * (uu + du) + p[2], p[1] * (vv + dv) + p[3]};
    }
    default:
      ADD_FAILURE() << "no reference for model " << static_cast<int>(camera.model_id);
      return Eigen::Vector2d::Zero();
  }
}

class CameraModelTest : public ::testing::TestWithParam<CameraModelId> {};

TEST_P(CameraModelTest, ImgFromCamMatchesColmapFormulas) {
  std::mt19937 rng(50 + static_cast<int>(GetParam()));
  for (int c = 0; c < kCamerasPerModel; ++c) {
    const Camera camera = RandomCamera(GetParam(), rng);
    for (int p = 0; p < kPointsPerCamera; ++p) {
      const Eigen::Vector2d normalized = RandomNormalized(MaxFieldAngle(GetParam()), rng);
      ASSERT_TRUE(
          VectorsNear(camera.ImgFromCam(normalized), ColmapImgFromCam(camera, normalized), 1e-9))
          << Describe(camera);
    }
  }
}

TEST_P(CameraModelTest, CamFromImgInvertsImgFromCam) {
  std::mt19937 rng(100 + static_cast<int>(GetParam()));
  for (int c = 0; c < kCamerasPerModel; ++c) {
    const Camera camera = RandomCamera(GetParam(), rng);
    for (int p = 0; p < kPointsPerCamera; ++p) {
      const Eigen::Vector2d normalized = RandomNormalized(MaxFieldAngle(GetParam()), rng);
      const Eigen::Vector2d round_trip = camera.CamFromImg(camera.ImgFromCam(normalized));
      ASSERT_TRUE(VectorsNear(round_trip, normalized, 1e-10)) << Describe(camera);
    }
  }
}

TEST_P(CameraModelTest, ImgFromCamInvertsCamFromImgInsideTheImage) {
  std::mt19937 rng(200 + static_cast<int>(GetParam()));
  for (int c = 0; c < kCamerasPerModel; ++c) {
    const Camera camera = RandomCamera(GetParam(), rng);
    for (int p = 0; p < kPointsPerCamera; ++p) {
      const Eigen::Vector2d pixel(Uniform(rng, 0.0, camera.width),
                                  Uniform(rng, 0.0, camera.height));
      const Eigen::Vector2d normalized = camera.CamFromImg(pixel);
      ASSERT_TRUE(normalized.allFinite()) << Describe(camera) << " pixel " << pixel.transpose();
      ASSERT_TRUE(VectorsNear(camera.ImgFromCam(normalized), pixel, 1e-9)) << Describe(camera);
    }
  }
}

TEST_P(CameraModelTest, PrincipalPointIsTheOpticalAxis) {
  std::mt19937 rng(300 + static_cast<int>(GetParam()));
  const Camera camera = RandomCamera(GetParam(), rng);
  const Eigen::Vector2d principal_point = camera.ImgFromCam(Eigen::Vector2d::Zero());
  EXPECT_TRUE(VectorsNear(camera.CamFromImg(principal_point), Eigen::Vector2d::Zero(), 1e-15));
}

TEST_P(CameraModelTest, NameAndIdRoundTrip) {
  const CameraModelId model_id = GetParam();
  EXPECT_TRUE(IsKnownCameraModelId(static_cast<int>(model_id)));
  EXPECT_EQ(CameraModelIdFromName(CameraModelName(model_id)), model_id);
}

TEST_P(CameraModelTest, FromModelNameRejectsAWrongParamCount) {
  const std::string name = CameraModelName(GetParam());
  const size_t num_params = CameraModelNumParams(GetParam());
  for (const size_t wrong_count : {num_params - 1, num_params + 1}) {
    try {
      Camera::FromModelName(3, name, 640, 480, std::vector<double>(wrong_count, 500.0));
      FAIL() << name << " accepted " << wrong_count << " params";
    } catch (const std::invalid_argument& error) {
      EXPECT_THAT(error.what(), HasSubstr("params"));
      EXPECT_THAT(error.what(), HasSubstr(name));
    }
  }
}

INSTANTIATE_TEST_SUITE_P(AllModels, CameraModelTest, ::testing::ValuesIn(kAllModels),
                         [](const ::testing::TestParamInfo<CameraModelId>& info) {
                           std::string name = CameraModelName(info.param);
                           name.erase(std::remove(name.begin(), name.end(), '_'), name.end());
                           return name;
                         });

TEST(CameraModel, IdsNamesAndParamCountsMatchColmap) {
  const std::vector<std::pair<std::string, size_t>> expected = {{"SIMPLE_PINHOLE", 3},
                                                                {"PINHOLE", 4},
                                                                {"SIMPLE_RADIAL", 4},
                                                                {"RADIAL", 5},
                                                                {"OPENCV", 8},
                                                                {"OPENCV_FISHEYE", 8},
                                                                {"FULL_OPENCV", 12},
                                                                {"FOV", 5},
                                                                {"SIMPLE_RADIAL_FISHEYE", 4},
                                                                {"RADIAL_FISHEYE", 5},
                                                                {"THIN_PRISM_FISHEYE", 12}};
  for (int id = 0; id < static_cast<int>(expected.size()); ++id) {
    const CameraModelId model_id = static_cast<CameraModelId>(id);
    EXPECT_EQ(CameraModelName(model_id), expected[id].first);
    EXPECT_EQ(CameraModelIdFromName(expected[id].first), model_id);
    EXPECT_EQ(CameraModelNumParams(model_id), expected[id].second) << expected[id].first;
  }
}

TEST(CameraModel, UnknownIdsAndNamesAreRejected) {
  EXPECT_FALSE(IsKnownCameraModelId(-1));
  EXPECT_FALSE(IsKnownCameraModelId(11));
  EXPECT_THROW(CameraModelName(CameraModelId::kInvalid), std::invalid_argument);
  EXPECT_THROW(CameraModelNumParams(static_cast<CameraModelId>(42)), std::invalid_argument);
  try {
    CameraModelIdFromName("WIDE_ANGLE_9000");
    FAIL() << "an unknown name was accepted";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("WIDE_ANGLE_9000"));
  }
  // Names are COLMAP's exact spelling.
  EXPECT_THROW(CameraModelIdFromName("pinhole"), std::invalid_argument);
}

TEST(Camera, FromModelNameRejectsAnUnknownName) {
  try {
    Camera::FromModelName(3, "WIDE_ANGLE_9000", 640, 480, {500.0, 320.0, 240.0});
    FAIL() << "an unknown name was accepted";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("WIDE_ANGLE_9000"));
  }
}

TEST(Camera, FromModelNameBuildsACheckedCamera) {
  const Camera camera = Camera::FromModelName(3, "PINHOLE", 640, 480, {500.0, 600.0, 320.0, 240.0});
  EXPECT_EQ(camera.camera_id, 3u);
  EXPECT_EQ(camera.model_id, CameraModelId::kPinhole);
  EXPECT_EQ(camera.width, 640u);
  EXPECT_EQ(camera.height, 480u);
  EXPECT_DOUBLE_EQ(camera.MeanFocalLength(), 550.0);
}

TEST(Camera, MeanFocalLengthOfASingleFocalModel) {
  const Camera camera =
      Camera::FromModelName(1, "SIMPLE_RADIAL", 640, 480, {700.0, 320.0, 240.0, 0.01});
  EXPECT_DOUBLE_EQ(camera.MeanFocalLength(), 700.0);
}

std::string CheckMessage(const Camera& camera) {
  try {
    camera.Check();
  } catch (const std::invalid_argument& error) {
    return error.what();
  }
  return "Check() did not throw";
}

TEST(Camera, CheckNamesTheBadField) {
  Camera good;
  good.camera_id = 7;
  good.model_id = CameraModelId::kOpenCV;
  good.width = 640;
  good.height = 480;
  good.params = {500.0, 510.0, 320.0, 240.0, 0.01, 0.0, 0.0, 0.0};
  EXPECT_NO_THROW(good.Check());

  Camera bad = good;
  bad.model_id = static_cast<CameraModelId>(42);
  EXPECT_THAT(CheckMessage(bad), HasSubstr("camera 7: model_id 42"));
  bad = good;
  bad.model_id = CameraModelId::kInvalid;
  EXPECT_THAT(CheckMessage(bad), HasSubstr("camera 7: model_id -1"));
  bad = good;
  bad.params.pop_back();
  EXPECT_THAT(CheckMessage(bad), HasSubstr("camera 7: params holds 7 values, OPENCV takes 8"));
  bad = good;
  bad.width = 0;
  EXPECT_THAT(CheckMessage(bad), HasSubstr("camera 7: width"));
  bad = good;
  bad.height = 0;
  EXPECT_THAT(CheckMessage(bad), HasSubstr("camera 7: height"));
  bad = good;
  bad.params[5] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THAT(CheckMessage(bad), HasSubstr("camera 7: params[5] is nan"));
  bad = good;
  bad.params[2] = std::numeric_limits<double>::infinity();
  EXPECT_THAT(CheckMessage(bad), HasSubstr("camera 7: params[2] is inf"));
  bad = good;
  bad.params[1] = 0.0;
  EXPECT_THAT(CheckMessage(bad), HasSubstr("camera 7: focal length params[1]"));
  bad = good;
  bad.params[0] = -500.0;
  EXPECT_THAT(CheckMessage(bad), HasSubstr("camera 7: focal length params[0]"));
}

TEST(Camera, ProjectionRejectsParamsThatDoNotMatchTheModel) {
  Camera camera = Camera::FromModelName(1, "PINHOLE", 640, 480, {500.0, 500.0, 320.0, 240.0});
  camera.params.pop_back();
  EXPECT_THROW(camera.ImgFromCam(Eigen::Vector2d::Zero()), std::invalid_argument);
  EXPECT_THROW(camera.CamFromImg(Eigen::Vector2d::Zero()), std::invalid_argument);
  camera.model_id = CameraModelId::kInvalid;
  EXPECT_THROW(camera.MeanFocalLength(), std::invalid_argument);
}

TEST(Camera, UndistortedModelsAreThePinholeFormula) {
  std::mt19937 rng(400);
  for (int trial = 0; trial < 100; ++trial) {
    const double fx = Uniform(rng, 300.0, 2000.0);
    const double fy = Uniform(rng, 300.0, 2000.0);
    const double cx = Uniform(rng, 300.0, 340.0);
    const double cy = Uniform(rng, 220.0, 260.0);
    const Eigen::Vector2d normalized = RandomNormalized(0.6, rng);
    const Eigen::Vector2d pinhole_f(fx * normalized.x() + cx, fx * normalized.y() + cy);
    const Eigen::Vector2d pinhole_fxfy(fx * normalized.x() + cx, fy * normalized.y() + cy);
    struct Case {
      std::string name;
      std::vector<double> params;
      Eigen::Vector2d expected;
    };
    // Every perspective model reduces to the pinhole when its distortion is zero; FOV does at
    // omega = 0.
    const std::vector<Case> cases = {
        {"SIMPLE_PINHOLE", {fx, cx, cy}, pinhole_f},
        {"SIMPLE_RADIAL", {fx, cx, cy, 0.0}, pinhole_f},
        {"RADIAL", {fx, cx, cy, 0.0, 0.0}, pinhole_f},
        {"PINHOLE", {fx, fy, cx, cy}, pinhole_fxfy},
        {"OPENCV", {fx, fy, cx, cy, 0.0, 0.0, 0.0, 0.0}, pinhole_fxfy},
        {"FULL_OPENCV", {fx, fy, cx, cy, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0}, pinhole_fxfy},
        {"FOV", {fx, fy, cx, cy, 0.0}, pinhole_fxfy},
    };
    for (const auto& [name, params, expected] : cases) {
      const Camera camera = Camera::FromModelName(1, name, 640, 480, params);
      EXPECT_TRUE(VectorsNear(camera.ImgFromCam(normalized), expected, 1e-9)) << name;
      EXPECT_TRUE(VectorsNear(camera.CamFromImg(expected), normalized, 1e-14)) << name;
    }
  }
}

TEST(Camera, SimpleRadialKnownValue) {
  // r^2 = 0.3^2 + 0.4^2 = 0.25, so the distortion factor is 1 + 0.1 * 0.25 = 1.025:
  // (0.3075, 0.41) -> (50 + 100 * 0.3075, 40 + 100 * 0.41).
  const Camera camera =
      Camera::FromModelName(1, "SIMPLE_RADIAL", 100, 80, {100.0, 50.0, 40.0, 0.1});
  EXPECT_TRUE(VectorsNear(camera.ImgFromCam({0.3, 0.4}), {80.75, 81.0}, 1e-12));
  EXPECT_TRUE(VectorsNear(camera.CamFromImg({80.75, 81.0}), {0.3, 0.4}, 1e-14));
}

TEST(Camera, FisheyeKnownValue) {
  // 45 degrees off axis: theta = pi / 4, theta_d = theta (1 + k theta^2).
  const Camera camera =
      Camera::FromModelName(1, "SIMPLE_RADIAL_FISHEYE", 100, 80, {100.0, 50.0, 40.0, 0.1});
  const double theta_d = M_PI / 4.0 * (1.0 + 0.1 * M_PI * M_PI / 16.0);
  EXPECT_TRUE(VectorsNear(camera.ImgFromCam({1.0, 0.0}), {50.0 + 100.0 * theta_d, 40.0}, 1e-12));
  EXPECT_TRUE(VectorsNear(camera.CamFromImg({50.0, 40.0 + 100.0 * theta_d}), {0.0, 1.0}, 1e-14));
}

TEST(Camera, FovFollowsTheClosedFormForSmallOmega) {
  // Below omega = 0.01 COLMAP 3.8 uses a series with the wrong sign; the closed form is the model.
  for (const double omega : {0.005, 0.5}) {
    const Camera camera =
        Camera::FromModelName(1, "FOV", 100, 80, {100.0, 100.0, 50.0, 40.0, omega});
    const double r = 0.8;
    const double expected_radius = std::atan(2.0 * r * std::tan(omega / 2.0)) / omega;
    EXPECT_TRUE(
        VectorsNear(camera.ImgFromCam({r, 0.0}), {50.0 + 100.0 * expected_radius, 40.0}, 1e-12))
        << "omega " << omega;
  }
}

TEST(Camera, FovIsContinuousAcrossItsSeriesThreshold) {
  const Eigen::Vector2d normalized(0.5, -0.3);
  Eigen::Vector2d previous;
  for (const double omega : {0.0, 0.999e-6, 1.001e-6, 1e-5}) {
    const Camera camera =
        Camera::FromModelName(1, "FOV", 100, 80, {1000.0, 1000.0, 50.0, 40.0, omega});
    const Eigen::Vector2d pixel = camera.ImgFromCam(normalized);
    if (omega > 0.0) {
      EXPECT_TRUE(VectorsNear(pixel, previous, 1e-7)) << "omega " << omega;
    }
    EXPECT_TRUE(VectorsNear(camera.CamFromImg(pixel), normalized, 1e-14)) << "omega " << omega;
    previous = pixel;
  }
}

TEST(Camera, CamFromImgReportsPixelsBeyondTheFold) {
  // r (1 - 0.5 r^2) peaks at 0.544 (r = 0.816): no ray reaches a larger distorted radius.
  const Camera simple_radial =
      Camera::FromModelName(1, "SIMPLE_RADIAL", 2000, 2000, {1000.0, 1000.0, 1000.0, -0.5});
  const Camera opencv = Camera::FromModelName(
      1, "OPENCV", 2000, 2000, {1000.0, 1000.0, 1000.0, 1000.0, -0.5, 0.0, 0.0, 0.0});
  for (const Camera& camera : {simple_radial, opencv}) {
    const std::string name = CameraModelName(camera.model_id);
    EXPECT_TRUE(camera.CamFromImg({1000.0 + 500.0, 1000.0}).allFinite()) << name;
    for (const double distorted_radius : {0.55, 0.6, 0.8, 1.0, 1.5, 3.0}) {
      EXPECT_FALSE(camera.CamFromImg({1000.0 + 1000.0 * distorted_radius, 1000.0}).allFinite())
          << name << " at distorted radius " << distorted_radius;
    }
  }
}

TEST(Camera, CamFromImgReportsRaysAtNinetyDegreesAndBeyond) {
  // The equidistant fisheye images the angle theta at radius f theta; FOV with omega = 1 images
  // a ray at 90 degrees at radius f pi / 2.
  const Camera fisheye =
      Camera::FromModelName(1, "SIMPLE_RADIAL_FISHEYE", 400, 400, {100.0, 200.0, 200.0, 0.0});
  const Camera thin_prism =
      Camera::FromModelName(1, "THIN_PRISM_FISHEYE", 400, 400,
                            {100.0, 100.0, 200.0, 200.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0});
  const Camera fov = Camera::FromModelName(1, "FOV", 400, 400, {100.0, 100.0, 200.0, 200.0, 1.0});
  for (const Camera& camera : {fisheye, thin_prism, fov}) {
    const std::string name = CameraModelName(camera.model_id);
    EXPECT_TRUE(camera.CamFromImg({200.0 + 150.0, 200.0}).allFinite()) << name;
    EXPECT_FALSE(camera.CamFromImg({200.0 + 100.0 * M_PI / 2.0, 200.0}).allFinite()) << name;
    EXPECT_FALSE(camera.CamFromImg({200.0, 200.0 - 180.0}).allFinite()) << name;
  }
}

TEST(Camera, ImgFromPointInCamDividesByDepth) {
  const Camera camera =
      Camera::FromModelName(1, "SIMPLE_RADIAL", 640, 480, {500.0, 320.0, 240.0, 0.05});
  const Eigen::Vector3d point_in_cam(0.6, -0.4, 2.0);
  EXPECT_TRUE(
      VectorsNear(camera.ImgFromPointInCam(point_in_cam), camera.ImgFromCam({0.3, -0.2}), 1e-12));
}

TEST(Camera, IsInsideCoversTheClosedImageRectangle) {
  const Camera camera = Camera::FromModelName(1, "SIMPLE_PINHOLE", 640, 480, {500.0, 320.0, 240.0});
  EXPECT_TRUE(camera.IsInside({0.0, 0.0}));
  EXPECT_TRUE(camera.IsInside({640.0, 480.0}));
  EXPECT_FALSE(camera.IsInside({-0.1, 10.0}));
  EXPECT_FALSE(camera.IsInside({10.0, 480.1}));
}

}  // namespace
}  // namespace hscloc
