#include "bank/bank_builder.h"

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <iostream>
#include <opencv2/core.hpp>

#include "util/random.h"
#include "util/testing.h"

namespace hscloc {
namespace {

// A textured daylight photo: smooth gradients and random blocks.
cv::Mat DaylightPhoto() {
  cv::Mat photo(120, 160, CV_8UC3);
  Random random(11);
  for (int y = 0; y < photo.rows; ++y) {
    for (int x = 0; x < photo.cols; ++x) {
      const int block = static_cast<int>(MixBits((y / 8) * 64 + x / 8) % 120);
      photo.at<cv::Vec3b>(y, x) =
          cv::Vec3b(static_cast<uchar>(60 + block + x / 4), static_cast<uchar>(70 + block + y / 4),
                    static_cast<uchar>(90 + block));
    }
  }
  return photo;
}

TEST(BankSetNameTest, IsTheFolderNameHoweverThePathIsWritten) {
  EXPECT_EQ(BankSetName("data/lund"), "lund");
  EXPECT_EQ(BankSetName("data/lund/"), "lund");
  EXPECT_EQ(BankSetName("./data/../data/lund"), "lund");
  EXPECT_EQ(BankSetName("/srv/sets/kitti-07"), "kitti-07");
}

TEST(NightPhotoTest, IsDarkerWarmerAndTheSameForTheSameKey) {
  const cv::Mat day = DaylightPhoto();
  const NightTransformOptions options;
  const cv::Mat night = NightPhoto(day, options, 3);
  ASSERT_EQ(night.size(), day.size());
  ASSERT_EQ(night.type(), CV_8UC3);
  const cv::Scalar day_mean = cv::mean(day);
  const cv::Scalar night_mean = cv::mean(night);
  for (int c = 0; c < 3; ++c) EXPECT_LT(night_mean[c], day_mean[c]) << "channel " << c;
  // Sodium light: blue loses more than red.
  EXPECT_LT(night_mean[0] / night_mean[2], day_mean[0] / day_mean[2]);
  EXPECT_EQ(cv::norm(night, NightPhoto(day, options, 3), cv::NORM_L1), 0.0);
  EXPECT_GT(cv::norm(night, NightPhoto(day, options, 4), cv::NORM_L1), 0.0);
  NightTransformOptions bad;
  bad.exposure_min = 0;
  EXPECT_THROW(NightPhoto(day, bad, 3), std::invalid_argument);
}

// Three cameras on a line looking along +z at three points; point 3 is seen once.
struct TinySet {
  Reconstruction reconstruction;
  testing::TempDir temp;
};

void MakeTinySet(TinySet& set) {
  Reconstruction& r = set.reconstruction;
  Camera camera;
  camera.camera_id = 1;
  camera.model_id = CameraModelId::kSimplePinhole;
  camera.width = 100;
  camera.height = 100;
  camera.params = {100, 50, 50};
  r.cameras[1] = camera;
  const std::vector<Eigen::Vector3d> points = {{0, 0, 10}, {1, 0, 10}, {-1, 1, 12}};
  for (image_t id = 1; id <= 3; ++id) {
    Image image;
    image.image_id = id;
    image.name = fmt::format("{}.jpg", id);
    image.camera_id = 1;
    image.cam_from_world.translation = Eigen::Vector3d(-(static_cast<double>(id) - 2), 0, 0);
    r.images[id] = image;
  }
  for (point3D_t p = 1; p <= 3; ++p) {
    Point3D point;
    point.xyz = points[p - 1];
    const image_t seen_by = p == 3 ? 1 : 3;
    for (image_t id = 1; id <= seen_by; ++id) {
      Image& image = r.images[id];
      Point2D point2D;
      point2D.xy = camera.ImgFromPointInCam(image.cam_from_world * point.xyz);
      point2D.point3D_id = p;
      point.track.push_back({id, static_cast<point2D_t>(image.points2D.size())});
      image.points2D.push_back(point2D);
    }
    r.points3D[p] = point;
  }
}

// Day features at the 2D points (descriptor: one-hot of image and point); night features with
// the same keypoints moved by `shift` px, and image 2's keypoints missing at night.
void WriteFeatures(const TinySet& set, const std::filesystem::path& day_path,
                   const std::filesystem::path& night_path, float shift) {
  H5FeatureWriter day(day_path, H5FloatPrecision::kFloat32);
  H5FeatureWriter night(night_path, H5FloatPrecision::kFloat32);
  for (const auto& [id, image] : set.reconstruction.images) {
    ImageFeatures features;
    const auto n = static_cast<int64_t>(image.points2D.size());
    features.keypoints.resize(n, 2);
    features.descriptors.setZero(n, 8);
    for (int64_t k = 0; k < n; ++k) {
      features.keypoints.row(k) = image.points2D[k].xy.cast<float>().transpose();
      features.descriptors(k, id) = 3;
      features.descriptors(k, 4 + image.points2D[k].point3D_id) = 4;
    }
    day.Write(image.name, features, 100, 100);
    ImageFeatures dark = features;
    dark.keypoints.array() += shift;
    dark.descriptors *= -1;
    if (id == 2) {
      dark.keypoints.resize(1, 2);
      dark.keypoints << 0, 0;
      dark.descriptors = Eigen::RowVectorXf::Ones(8);
    }
    night.Write(image.name, dark, 100, 100);
  }
  day.Close();
  night.Close();
}

TEST(BankFromReconstructionTest, KeepsEveryViewOfEachTrackWithItsNightDescriptor) {
  TinySet set;
  MakeTinySet(set);
  WriteFeatures(set, set.temp / "day.h5", set.temp / "night.h5", 0.5f);
  const auto day = OpenFeatureReader(set.temp / "day.h5");
  const auto night = OpenFeatureReader(set.temp / "night.h5");
  const DescriptorBank bank =
      BankFromReconstruction(set.reconstruction, *day, night.get(), 2.0, 2, "test", "tiny");
  // Point 3 has a single view: not a track.
  ASSERT_EQ(bank.NumTracks(), 2u);
  ASSERT_EQ(bank.NumViews(), 6u);
  EXPECT_EQ(bank.sources(), std::vector<std::string>{"tiny"});
  for (size_t t = 0; t < 2; ++t) {
    for (uint32_t v = bank.FirstView(t); v < bank.EndView(t); ++v) {
      const int image = static_cast<int>(v - bank.FirstView(t)) + 1;
      // The view's own descriptor: its image's and its point's one-hot parts, as a unit row.
      EXPECT_NEAR(bank.day()(v, image), 0.6f, 1e-6f);
      EXPECT_NEAR(bank.day()(v, 5 + t), 0.8f, 1e-6f);
      // Found again at night half a pixel away, except in image 2.
      EXPECT_EQ(bank.HasNight(v), image != 2);
      if (bank.HasNight(v)) EXPECT_NEAR(bank.night()(v, 5 + t), -0.8f, 1e-6f);
    }
    // The middle camera sees the points nearest the track's mean direction, and the outer ones
    // lie on either side of it.
    EXPECT_EQ(bank.NearestView(t, Eigen::Vector2f::Zero()), bank.FirstView(t) + 1);
    EXPECT_LT(bank.directions()(bank.FirstView(t), 0) * bank.directions()(bank.FirstView(t) + 2, 0),
              0.0f);
  }
  // A night keypoint farther than the radius is not the view's.
  WriteFeatures(set, set.temp / "day2.h5", set.temp / "night2.h5", 3.0f);
  const auto far = OpenFeatureReader(set.temp / "night2.h5");
  EXPECT_EQ(BankFromReconstruction(set.reconstruction, *OpenFeatureReader(set.temp / "day2.h5"),
                                   far.get(), 2.0, 2, "test", "tiny")
                .NumNightViews(),
            0u);
}

// Lund's photos with XFeat: the set's tracks, most of their views found again at night, as the
// suite's real-data tests find the set. Skips without the set, XFeat's weights or COLMAP.
TEST(BankFromSetTest, LundWithXFeat) {
  HSCLOC_REQUIRE_REAL_DATA(data, "lund");
  HSCLOC_REQUIRE_REAL_DATA(weights, "weights/xfeat");
  HSCLOC_REQUIRE_COLMAP(colmap);
  testing::TempDir temp;
  BankSetOptions options;
  options.extractor.type = FeatureType::kXFeat;
  options.extractor.xfeat.model_path = (weights / "xfeat.onnx").string();
  options.triangulation.colmap.colmap_executable = colmap;
  options.show_progress = false;
  // Through BankFromSets with the path written with a trailing slash: the set keeps its name.
  int sets_done = 0;
  const DescriptorBank bank =
      BankFromSets({data.string() + "/"}, temp / "work", options,
                   [&](const std::filesystem::path&, const DescriptorBank& set_bank, double) {
                     ++sets_done;
                     EXPECT_GT(set_bank.NumTracks(), 0u);
                   });
  EXPECT_EQ(sets_done, 1);
  EXPECT_EQ(bank.sources(), std::vector<std::string>{"lund"});
  EXPECT_TRUE(std::filesystem::is_directory(temp / "work" / "1-lund"));
  const double night_share =
      static_cast<double>(bank.NumNightViews()) / static_cast<double>(bank.NumViews());
  std::cout << fmt::format("lund, XFeat: {} tracks, {} views, {:.1f} % found again at night\n",
                           bank.NumTracks(), bank.NumViews(), 100 * night_share);
  EXPECT_EQ(bank.feature(), "xfeat");
  EXPECT_EQ(bank.dimension(), 64);
  EXPECT_GT(bank.NumTracks(), 1000u);
  EXPECT_GE(bank.NumViews(), 2 * bank.NumTracks());
  // The night transform loses keypoints, but not most of them.
  EXPECT_GT(night_share, 0.2);
  EXPECT_LT(night_share, 0.95);
  // A view's night descriptor is closer to its own day descriptor than to other tracks' on
  // average: the same keypoint, described again.
  double own = 0, other = 0;
  int count = 0;
  for (uint32_t v = 0; v + 100 < bank.NumViews(); ++v) {
    if (!bank.HasNight(v)) continue;
    own += bank.night().row(v).dot(bank.day().row(v));
    other += bank.night().row(v).dot(bank.day().row(v + 100));
    ++count;
  }
  ASSERT_GT(count, 0);
  EXPECT_GT(own / count, other / count + 0.3);
  // A second run over the same work folder resumes and gives the same bank.
  EXPECT_EQ(BankFromSet(data, temp / "work", options), bank);
}

}  // namespace
}  // namespace hscloc
