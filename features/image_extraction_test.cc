#include "features/image_extraction.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;

// A textured photo that SIFT finds keypoints in: discs of several sizes on a noisy background.
void WriteTexturedPhoto(const std::filesystem::path& path, int width, int height, int seed) {
  cv::Mat image(height, width, CV_8UC3);
  cv::RNG random(seed);
  random.fill(image, cv::RNG::UNIFORM, 0, 60);
  for (int i = 0; i < 30; ++i) {
    cv::circle(image, cv::Point(random.uniform(0, width), random.uniform(0, height)),
               random.uniform(3, 20), cv::Scalar::all(random.uniform(120, 255)), cv::FILLED);
  }
  std::filesystem::create_directories(path.parent_path());
  cv::imwrite(path.string(), image);
}

ImageExtractionOptions QuietOptions(FeatureType type) {
  ImageExtractionOptions options;
  options.extractor.type = type;
  options.num_threads = 2;
  options.show_progress = false;
  return options;
}

TEST(ImageExtractionTest, ListsPhotosRecursivelyAndReadsLists) {
  testing::TempDir dir;
  WriteTexturedPhoto(dir / "images" / "b.JPG", 40, 30, 1);
  WriteTexturedPhoto(dir / "images" / "sub" / "a.png", 40, 30, 2);
  std::ofstream(dir / "images" / "notes.txt") << "not a photo";
  EXPECT_THAT(ListImages(dir / "images"), ElementsAre("b.JPG", "sub/a.png"));
  std::ofstream(dir / "list.txt") << "sub/a.png\n\n  b.JPG \n";
  EXPECT_THAT(ReadImageList(dir / "list.txt"), ElementsAre("sub/a.png", "b.JPG"));

  EXPECT_THAT(testing::InvalidArgumentMessage([&] { ListImages(dir / "missing"); }),
              HasSubstr((dir / "missing").string()));
  std::filesystem::create_directories(dir / "empty");
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { ListImages(dir / "empty"); }),
              HasSubstr("holds no photo"));
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { ReadImageList(dir / "missing.txt"); }),
              HasSubstr((dir / "missing.txt").string()));
}

TEST(ImageExtractionTest, WritesHlocFeaturesAndResumes) {
  testing::TempDir dir;
  WriteTexturedPhoto(dir / "images" / "seq" / "1.png", 320, 240, 1);
  WriteTexturedPhoto(dir / "images" / "seq" / "2.png", 200, 300, 2);
  const auto out = dir / "features.h5";
  const ImageExtractionOptions options = QuietOptions(FeatureType::kSift);
  const ImageExtractionSummary first =
      ExtractImagesToH5(dir / "images", {"seq/1.png"}, out, options);
  EXPECT_EQ(first.num_extracted, 1);
  EXPECT_GT(first.num_keypoints, 10);

  // The second run keeps the first image as it is and adds the other one.
  const ImageExtractionSummary second =
      ExtractImagesToH5(dir / "images", ListImages(dir / "images"), out, options);
  EXPECT_EQ(second.num_images, 2);
  EXPECT_EQ(second.num_skipped, 1);
  EXPECT_EQ(second.num_extracted, 1);
  const auto reader = OpenFeatureReader(out);
  EXPECT_THAT(reader->ImageNames(), ElementsAre("seq/1.png", "seq/2.png"));
  const ImageFeatures read = reader->Read("seq/1.png");
  EXPECT_EQ(read.NumKeypoints(), first.num_keypoints);
  EXPECT_EQ(read.Dimension(), 128);
  EXPECT_EQ(read.scores.size(), read.NumKeypoints());
  // Stored in half precision: unit norm within float16 rounding.
  EXPECT_NEAR(read.descriptors.row(0).norm(), 1.0f, 1e-2);
}

TEST(ImageExtractionTest, ABadImageStopsTheRunNamingIt) {
  testing::TempDir dir;
  WriteTexturedPhoto(dir / "images" / "1.png", 320, 240, 1);
  std::ofstream(dir / "images" / "2.jpg") << "not an image";
  const ImageExtractionOptions options = QuietOptions(FeatureType::kSift);
  EXPECT_THAT(testing::InvalidArgumentMessage([&] {
                ExtractImagesToH5(dir / "images", {"1.png", "2.jpg"}, dir / "f.h5", options);
              }),
              HasSubstr((dir / "images" / "2.jpg").string()));
  EXPECT_THAT(testing::InvalidArgumentMessage([&] {
                ExtractImagesToH5(dir / "images", {"missing.png"}, dir / "f.h5", options);
              }),
              HasSubstr("missing.png"));
}

TEST(ImageExtractionTest, XFeatOnRealPhotos) {
  HSCLOC_REQUIRE_REAL_DATA(lund, "lund/images");
  HSCLOC_REQUIRE_REAL_DATA(weights, "weights/xfeat");
  testing::TempDir dir;
  ImageExtractionOptions options = QuietOptions(FeatureType::kXFeat);
  options.extractor.xfeat.model_path = (weights / "xfeat.onnx").string();
  const ImageExtractionSummary summary =
      ExtractImagesToH5(lund, {"01.jpg", "02.jpg"}, dir / "f.h5", options);
  EXPECT_EQ(summary.num_extracted, 2);
  const cv::Mat photo = cv::imread((lund / "02.jpg").string());
  const ImageFeatures read = OpenFeatureReader(dir / "f.h5")->Read("02.jpg");
  EXPECT_EQ(read.NumKeypoints(), options.extractor.xfeat.max_keypoints);
  EXPECT_EQ(read.Dimension(), 64);
  EXPECT_LE(read.keypoints.col(0).maxCoeff(), photo.cols);
  EXPECT_LE(read.keypoints.col(1).maxCoeff(), photo.rows);

  options.extractor.xfeat.model_path = (dir / "missing.onnx").string();
  EXPECT_THAT(testing::InvalidArgumentMessage(
                  [&] { ExtractImagesToH5(lund, {"01.jpg"}, dir / "g.h5", options); }),
              HasSubstr("missing.onnx"));
  EXPECT_FALSE(std::filesystem::exists(dir / "g.h5"));
}

}  // namespace
}  // namespace hscloc
