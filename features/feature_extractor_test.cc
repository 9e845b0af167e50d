#include "features/feature_extractor.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;

// A bright rectangle, its corners on pixel boundaries, on a dark noisy background (XFeat, trained
// on photos, finds almost nothing on flat synthetic shapes).
std::filesystem::path WriteRectanglePhoto(const std::filesystem::path& path, int width, int height,
                                          const cv::Rect& rectangle) {
  cv::Mat image(height, width, CV_8UC3);
  cv::RNG(7).fill(image, cv::RNG::UNIFORM, 0, 60);
  cv::rectangle(image, rectangle, cv::Scalar(230, 230, 230), cv::FILLED);
  cv::imwrite(path.string(), image);
  return path;
}

std::filesystem::path WriteFlatPhoto(const std::filesystem::path& path) {
  cv::imwrite(path.string(), cv::Mat(200, 300, CV_8UC3, cv::Scalar(90, 90, 90)));
  return path;
}

std::filesystem::path WriteNotAnImage(const std::filesystem::path& path) {
  std::ofstream(path) << "not an image";
  return path;
}

void ExpectUnitDescriptors(const ExtractedFeatures& extracted, int dimension) {
  const ImageFeatures& features = extracted.features;
  ASSERT_GT(features.NumKeypoints(), 0);
  EXPECT_EQ(features.Dimension(), dimension);
  EXPECT_EQ(features.scores.size(), features.NumKeypoints());
  for (Eigen::Index i = 0; i < features.NumKeypoints(); ++i) {
    EXPECT_NEAR(features.descriptors.row(i).norm(), 1.0f, 1e-5) << "keypoint " << i;
    EXPECT_GE(features.keypoints(i, 0), 0);
    EXPECT_LE(features.keypoints(i, 0), extracted.width);
    EXPECT_GE(features.keypoints(i, 1), 0);
    EXPECT_LE(features.keypoints(i, 1), extracted.height);
  }
}

TEST(FeatureTypeTest, ParsesTheNamesAndRejectsOthers) {
  EXPECT_EQ(ParseFeatureType("sift"), FeatureType::kSift);
  EXPECT_EQ(ParseFeatureType("xfeat"), FeatureType::kXFeat);
  EXPECT_EQ(FeatureTypeName(FeatureType::kXFeat), "xfeat");
  EXPECT_THAT(testing::InvalidArgumentMessage([] { ParseFeatureType("orb"); }), HasSubstr("orb"));
}

TEST(SiftExtractorTest, FindsTheCornersWithUnitDescriptors) {
  testing::TempDir dir;
  const cv::Rect rectangle(100, 60, 120, 80);
  const auto photo = WriteRectanglePhoto(dir / "photo.png", 320, 240, rectangle);
  SiftExtractor sift({});
  const ExtractedFeatures extracted = sift.Extract(photo);
  EXPECT_EQ(extracted.width, 320);
  EXPECT_EQ(extracted.height, 240);
  ExpectUnitDescriptors(extracted, 128);
}

TEST(SiftExtractorTest, BadOrFeaturelessImagesNameTheFile) {
  testing::TempDir dir;
  SiftExtractor sift({});
  const auto bad = WriteNotAnImage(dir / "bad.jpg");
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { sift.Extract(bad); }), HasSubstr(bad.string()));
  const auto flat = WriteFlatPhoto(dir / "flat.png");
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { sift.Extract(flat); }),
              ::testing::AllOf(HasSubstr(flat.string()), HasSubstr("no keypoint")));
}

TEST(SiftExtractorTest, OptionsNameTheBadField) {
  FeatureExtractorOptions options;
  options.sift.max_keypoints = 0;
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { CreateFeatureExtractor(options); }),
              HasSubstr("max_keypoints"));
}

XFeatOptions XFeatOptionsFor(const std::filesystem::path& weights) {
  XFeatOptions options;
  options.model_path = (weights / "xfeat.onnx").string();
  return options;
}

TEST(XFeatExtractorTest, MissingOrInvalidModelsNameTheFile) {
  testing::TempDir dir;
  XFeatOptions options;
  options.model_path = (dir / "missing.onnx").string();
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { XFeatExtractor extractor(options); }),
              ::testing::AllOf(HasSubstr(options.model_path), HasSubstr("does not exist")));
  options.model_path = WriteNotAnImage(dir / "broken.onnx").string();
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { XFeatExtractor extractor(options); }),
              ::testing::AllOf(HasSubstr(options.model_path), HasSubstr("not a valid ONNX")));
  options.model_path.clear();
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { XFeatExtractor extractor(options); }),
              HasSubstr("model_path"));
}

TEST(XFeatExtractorTest, CornersLandOnTheirPixelsThroughTheResize) {
  HSCLOC_REQUIRE_REAL_DATA(weights, "weights/xfeat");
  testing::TempDir dir;
  // 1000 x 600 scales by 0.64 into 640 x 384 (padded below): one input pixel is 1.5625 px here.
  const cv::Rect rectangle(300, 200, 400, 250);
  const auto photo = WriteRectanglePhoto(dir / "photo.png", 1000, 600, rectangle);
  XFeatExtractor xfeat(XFeatOptionsFor(weights));
  const ExtractedFeatures extracted = xfeat.Extract(photo);
  EXPECT_EQ(extracted.width, 1000);
  EXPECT_EQ(extracted.height, 600);
  ExpectUnitDescriptors(extracted, 64);
  const KeypointMatrix& keypoints = extracted.features.keypoints;
  for (const cv::Point corner :
       {rectangle.tl(), rectangle.br(), cv::Point(rectangle.x + rectangle.width, rectangle.y),
        cv::Point(rectangle.x, rectangle.y + rectangle.height)}) {
    const Eigen::Vector2f expected(corner.x, corner.y);
    float nearest = std::numeric_limits<float>::infinity();
    for (Eigen::Index i = 0; i < keypoints.rows(); ++i) {
      nearest = std::min(nearest, (keypoints.row(i).transpose() - expected).norm());
    }
    // The network places a corner within 1 to 2.5 input pixels (measured); a wrong scale or a
    // padding offset would put it tens of pixels away. The next test checks the mapping exactly.
    EXPECT_LT(nearest, 3 * 1.5625f) << "corner " << corner;
  }
}

TEST(XFeatExtractorTest, MapsKeypointsBackExactlyAtAnyScale) {
  HSCLOC_REQUIRE_REAL_DATA(lund, "lund/images");
  HSCLOC_REQUIRE_REAL_DATA(weights, "weights/xfeat");
  testing::TempDir dir;
  // A photo that fills the input as it is, and the same photo at twice the size, each pixel
  // repeated 2 x 2: the network sees the same input for both.
  const cv::Mat original = cv::imread((lund / "01.jpg").string());
  ASSERT_FALSE(original.empty());
  const double scale = 640.0 / std::max(original.cols, original.rows);
  cv::Mat small, large;
  cv::resize(original, small, cv::Size(), scale, scale, cv::INTER_AREA);
  ASSERT_NE(small.cols, small.rows);
  cv::resize(small, large, cv::Size(), 2, 2, cv::INTER_NEAREST);
  cv::imwrite((dir / "small.png").string(), small);
  cv::imwrite((dir / "large.png").string(), large);
  XFeatExtractor xfeat(XFeatOptionsFor(weights));
  const ImageFeatures at_1 = xfeat.Extract(dir / "small.png").features;
  const ImageFeatures at_2 = xfeat.Extract(dir / "large.png").features;
  ASSERT_EQ(at_1.NumKeypoints(), at_2.NumKeypoints());
  // COLMAP coordinates scale about the image corner: a pixel centre (x, y) becomes (2x, 2y).
  EXPECT_TRUE(at_2.keypoints.isApprox(2 * at_1.keypoints, 1e-6f));
  EXPECT_EQ(at_1.descriptors, at_2.descriptors);
}

TEST(XFeatExtractorTest, IsDeterministic) {
  HSCLOC_REQUIRE_REAL_DATA(lund, "lund/images");
  HSCLOC_REQUIRE_REAL_DATA(weights, "weights/xfeat");
  XFeatExtractor xfeat(XFeatOptionsFor(weights));
  const ExtractedFeatures first = xfeat.Extract(lund / "01.jpg");
  const ExtractedFeatures second = xfeat.Extract(lund / "01.jpg");
  ExpectUnitDescriptors(first, 64);
  EXPECT_EQ(first.features.NumKeypoints(), 2048);
  EXPECT_EQ(first.features.keypoints, second.features.keypoints);
  EXPECT_EQ(first.features.descriptors, second.features.descriptors);
  EXPECT_EQ(first.features.scores, second.features.scores);
}

TEST(XFeatExtractorTest, BadOrFeaturelessImagesNameTheFile) {
  HSCLOC_REQUIRE_REAL_DATA(weights, "weights/xfeat");
  testing::TempDir dir;
  XFeatOptions options = XFeatOptionsFor(weights);
  options.score_threshold = 0.99f;
  XFeatExtractor xfeat(options);
  const auto bad = WriteNotAnImage(dir / "bad.jpg");
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { xfeat.Extract(bad); }),
              HasSubstr(bad.string()));
  const auto flat = WriteFlatPhoto(dir / "flat.png");
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { xfeat.Extract(flat); }),
              ::testing::AllOf(HasSubstr(flat.string()), HasSubstr("no keypoint")));
}

}  // namespace
}  // namespace hscloc
