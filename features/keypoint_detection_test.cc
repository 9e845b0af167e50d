#include "features/keypoint_detection.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <random>

namespace hscloc {
namespace {

TEST(KeypointHeatmapTest, PlacesEachBinAtItsPixelOfTheCell) {
  // 2 x 3 cells; cell (cy, cx) favours bin 9 * cy + 5 * cx + 1, i.e. pixel (row b / 8, col b % 8).
  const int cells_y = 2, cells_x = 3, plane = cells_y * cells_x;
  std::vector<float> logits(65 * plane, 0.0f);
  for (int cy = 0; cy < cells_y; ++cy) {
    for (int cx = 0; cx < cells_x; ++cx)
      logits[(9 * cy + 5 * cx + 1) * plane + cy * cells_x + cx] = 10;
  }
  const ScoreMap heatmap = KeypointHeatmap(logits.data(), cells_y, cells_x);
  ASSERT_EQ(heatmap.rows(), 16);
  ASSERT_EQ(heatmap.cols(), 24);
  for (int cy = 0; cy < cells_y; ++cy) {
    for (int cx = 0; cx < cells_x; ++cx) {
      const int bin = 9 * cy + 5 * cx + 1;
      const auto cell = heatmap.block(8 * cy, 8 * cx, 8, 8);
      Eigen::Index row, col;
      cell.maxCoeff(&row, &col);
      EXPECT_EQ(row, bin / 8);
      EXPECT_EQ(col, bin % 8);
      // The dustbin holds e^0 of the e^10 + 64 e^0 total: the 64 kept bins sum to the rest.
      EXPECT_NEAR(cell.sum(), 1.0 - 1.0 / (std::exp(10.0) + 64.0), 1e-5);
    }
  }
}

TEST(NonMaximumSuppressionTest, KeepsLocalMaximaMoreThanTheRadiusApart) {
  std::mt19937 random(7);
  std::uniform_real_distribution<float> uniform(0.0f, 1.0f);
  ScoreMap scores(120, 90);
  for (Eigen::Index i = 0; i < scores.size(); ++i) scores.data()[i] = uniform(random);
  const int radius = 4;
  const std::vector<Peak> peaks = NonMaximumSuppression(scores, radius, 0.1f, 1000);
  ASSERT_GT(peaks.size(), 50u);
  for (size_t i = 0; i < peaks.size(); ++i) {
    const Peak& peak = peaks[i];
    EXPECT_EQ(peak.score, scores(peak.y, peak.x));
    if (i > 0) {
      EXPECT_LE(peak.score, peaks[i - 1].score);
    }
    const int x0 = std::max(0, peak.x - radius), y0 = std::max(0, peak.y - radius);
    const int x1 = std::min(89, peak.x + radius), y1 = std::min(119, peak.y + radius);
    EXPECT_EQ(scores.block(y0, x0, y1 - y0 + 1, x1 - x0 + 1).maxCoeff(), peak.score);
    for (size_t j = 0; j < i; ++j) {
      EXPECT_GT(std::max(std::abs(peak.x - peaks[j].x), std::abs(peak.y - peaks[j].y)), radius)
          << "peaks " << i << " and " << j;
    }
  }
  EXPECT_EQ(NonMaximumSuppression(scores, radius, 0.1f, 10).size(), 10u);
  EXPECT_TRUE(NonMaximumSuppression(scores, radius, 1.0f, 10).empty());
}

TEST(NonMaximumSuppressionTest, KeepsOnePixelOfAPlateau) {
  ScoreMap scores = ScoreMap::Zero(20, 20);
  scores.block(5, 5, 3, 3).setConstant(0.5f);
  const std::vector<Peak> peaks = NonMaximumSuppression(scores, 4, 0.1f, 10);
  ASSERT_EQ(peaks.size(), 1u);
  EXPECT_EQ(peaks[0].x, 5);
  EXPECT_EQ(peaks[0].y, 5);
}

TEST(SampleDescriptorsTest, InterpolatesBilinearlyAndNormalizes) {
  // Two channels over 2 x 2 cells: channel 0 is the column, channel 1 is 1.
  const std::vector<float> map = {0, 1, 0, 1, /*channel 1*/ 1, 1, 1, 1};
  KeypointMatrix points(3, 2);
  points << 0.5f, 0.5f,  // centre of cell (0, 0)
      1.0f, 1.5f,        // halfway between the columns
      -3.0f, 9.0f;       // beyond the border: the border's value
  const DescriptorMatrix descriptors = SampleDescriptors(map.data(), 2, 2, 2, points);
  EXPECT_NEAR(descriptors(0, 0), 0.0f, 1e-6);
  EXPECT_NEAR(descriptors(0, 1), 1.0f, 1e-6);
  EXPECT_NEAR(descriptors(1, 0), 0.5f / std::sqrt(1.25f), 1e-6);
  EXPECT_NEAR(descriptors(1, 1), 1.0f / std::sqrt(1.25f), 1e-6);
  EXPECT_NEAR(descriptors(2, 0), 0.0f, 1e-6);
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(descriptors.row(i).norm(), 1.0f, 1e-6);
}

TEST(LetterboxTest, KeepsTheAspectAndMapsBackExactly) {
  const Letterbox landscape(1000, 600, 640);
  EXPECT_EQ(landscape.scaled_width, 640);
  EXPECT_EQ(landscape.scaled_height, 384);
  const Letterbox portrait(751, 1001, 640);
  EXPECT_EQ(portrait.scaled_width, 480);
  EXPECT_EQ(portrait.scaled_height, 640);
  // Corners of the photo land on the corners of the scaled area, pixel centres scale about them.
  EXPECT_TRUE(portrait.ToInput({751, 1001}).isApprox(Eigen::Vector2f(480, 640)));
  EXPECT_TRUE(landscape.ToInput({0.5f, 0.5f}).isApprox(Eigen::Vector2f(0.32f, 0.32f)));
  const Eigen::Vector2f photo(123.25f, 987.5f);
  EXPECT_TRUE(portrait.ToPhoto(portrait.ToInput(photo)).isApprox(photo, 1e-6f));
}

TEST(TileOriginsTest, FewestAlignedTilesThatOverlapEnoughAndCoverTheLength) {
  EXPECT_EQ(TileOrigins(640, 640, 128, 8), std::vector<int>{0});
  EXPECT_EQ(TileOrigins(1024, 640, 128, 8), (std::vector<int>{0, 384}));
  for (const int length : {648, 768, 1024, 1152, 1160, 1536, 2000, 4096}) {
    for (const int overlap : {0, 64, 100, 128, 632}) {
      const std::vector<int> origins = TileOrigins(length, 640, overlap, 8);
      ASSERT_FALSE(origins.empty());
      EXPECT_EQ(origins.front(), 0);
      EXPECT_EQ(origins.back(), length - 640) << length << " " << overlap;
      for (size_t i = 0; i < origins.size(); ++i) {
        EXPECT_EQ(origins[i] % 8, 0);
        if (i > 0) {
          EXPECT_GE(origins[i - 1] + 640 - origins[i], overlap) << length;
        }
      }
      // One tile fewer, at the largest stride the overlap allows, could not reach the end.
      const int stride = (640 - overlap) / 8 * 8;
      EXPECT_LT(640 + (static_cast<int>(origins.size()) - 2) * stride, length)
          << length << " " << overlap;
    }
  }
  EXPECT_THROW(TileOrigins(600, 640, 128, 8), std::invalid_argument);
  EXPECT_THROW(TileOrigins(1020, 640, 128, 8), std::invalid_argument);
}

TEST(NearestTileTest, EachPositionGoesToTheTileWhoseCentreIsNearest) {
  const std::vector<int> origins = {0, 384};  // centres 320 and 704
  EXPECT_EQ(NearestTile(origins, 640, 0.5f), 0);
  EXPECT_EQ(NearestTile(origins, 640, 511.5f), 0);
  EXPECT_EQ(NearestTile(origins, 640, 512.5f), 1);
  EXPECT_EQ(NearestTile(origins, 640, 1023.5f), 1);
}

}  // namespace
}  // namespace hscloc
