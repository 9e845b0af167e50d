#include "features/feature_extractor.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <fstream>
#include <map>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "features/keypoint_detection.h"
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
  // With the network's input as the longer side, 1000 x 600 scales by 0.64 into 640 x 384
  // (padded below): one input pixel is 1.5625 px here.
  const cv::Rect rectangle(300, 200, 400, 250);
  const auto photo = WriteRectanglePhoto(dir / "photo.png", 1000, 600, rectangle);
  XFeatOptions options = XFeatOptionsFor(weights);
  options.max_side_px = 640;
  XFeatExtractor xfeat(options);
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
  // A photo whose longer side is the largest the network sees, and the same photo at twice the
  // size, each pixel repeated 2 x 2: the network sees the same tiles for both.
  const cv::Mat original = cv::imread((lund / "01.jpg").string());
  ASSERT_FALSE(original.empty());
  const XFeatOptions options = XFeatOptionsFor(weights);
  const double scale =
      static_cast<double>(options.max_side_px) / std::max(original.cols, original.rows);
  cv::Mat small, large;
  cv::resize(original, small, cv::Size(), scale, scale, cv::INTER_AREA);
  ASSERT_NE(small.cols, small.rows);
  cv::resize(small, large, cv::Size(), 2, 2, cv::INTER_NEAREST);
  cv::imwrite((dir / "small.png").string(), small);
  cv::imwrite((dir / "large.png").string(), large);
  XFeatExtractor xfeat(options);
  const ImageFeatures at_1 = xfeat.Extract(dir / "small.png").features;
  const ImageFeatures at_2 = xfeat.Extract(dir / "large.png").features;
  ASSERT_EQ(at_1.NumKeypoints(), at_2.NumKeypoints());
  // COLMAP coordinates scale about the image corner: a pixel centre (x, y) becomes (2x, 2y).
  EXPECT_TRUE(at_2.keypoints.isApprox(2 * at_1.keypoints, 1e-6f));
  EXPECT_EQ(at_1.descriptors, at_2.descriptors);
}

// A photo larger than the network's input is seen through overlapping tiles: away from where one
// tile's cells give way to the next, the features are exactly those of the tile seen alone.
TEST(XFeatExtractorTest, EachCellComesFromTheTileWhereItIsMostCentral) {
  HSCLOC_REQUIRE_REAL_DATA(lund, "lund/images");
  HSCLOC_REQUIRE_REAL_DATA(weights, "weights/xfeat");
  testing::TempDir dir;
  const cv::Mat photo = cv::imread((lund / "01.jpg").string());
  ASSERT_EQ(photo.cols, 1024);
  ASSERT_EQ(photo.rows, 768);
  XFeatOptions options = XFeatOptionsFor(weights);
  options.max_keypoints = 1'000'000;  // no top-K: every peak of both runs is compared
  // 1024 x 768 is covered by 2 x 2 tiles; the last one, alone, is this crop.
  const std::vector<int> origins_x = TileOrigins(1024, 640, 128, 8);
  const std::vector<int> origins_y = TileOrigins(768, 640, 128, 8);
  ASSERT_EQ(origins_x.size(), 2u);
  ASSERT_EQ(origins_y.size(), 2u);
  const cv::Rect last_tile(origins_x[1], origins_y[1], 640, 640);
  cv::imwrite((dir / "tile.png").string(), photo(last_tile));
  XFeatExtractor xfeat(options);
  const ImageFeatures whole = xfeat.Extract(lund / "01.jpg").features;
  const ImageFeatures tile = xfeat.Extract(dir / "tile.png").features;
  // The last tile owns the cells past the midpoints between the tiles' centres; 16 px more keeps
  // NMS, the reliability's and the descriptors' interpolation from reaching across.
  const float owned_x = (origins_x[0] + origins_x[1] + 640) / 2.0f + 16;
  const float owned_y = (origins_y[0] + origins_y[1] + 640) / 2.0f + 16;
  const Eigen::Vector2f offset(last_tile.x, last_tile.y);
  const auto in_owned_region = [&](const Eigen::Vector2f& photo_px) {
    return photo_px.x() > owned_x && photo_px.y() > owned_y;
  };
  std::map<std::pair<float, float>, Eigen::Index> whole_at;
  for (Eigen::Index i = 0; i < whole.NumKeypoints(); ++i) {
    if (in_owned_region(whole.keypoints.row(i))) {
      whole_at[{whole.keypoints(i, 0), whole.keypoints(i, 1)}] = i;
    }
  }
  int compared = 0;
  for (Eigen::Index i = 0; i < tile.NumKeypoints(); ++i) {
    const Eigen::Vector2f in_photo = tile.keypoints.row(i).transpose() + offset;
    if (!in_owned_region(in_photo)) continue;
    const auto found = whole_at.find({in_photo.x(), in_photo.y()});
    ASSERT_NE(found, whole_at.end()) << "tile keypoint at " << in_photo.transpose();
    EXPECT_EQ(whole.scores(found->second), tile.scores(i));
    EXPECT_EQ(whole.descriptors.row(found->second), tile.descriptors.row(i));
    ++compared;
  }
  EXPECT_EQ(compared, static_cast<int>(whole_at.size()));
  EXPECT_GT(compared, 100);
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
