#include "localization/nearest_neighbor_matcher.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <vector>

#include "model/code_kernels.h"
#include "util/random.h"

namespace hscloc {
namespace {

using ::testing::ElementsAre;
using ::testing::IsEmpty;

// Random unit rows: distinct directions in 32-D are nearly orthogonal.
DescriptorMatrix RandomUnitRows(int rows, int dim, uint64_t seed) {
  Random random(seed);
  DescriptorMatrix descriptors(rows, dim);
  for (int i = 0; i < rows; ++i) {
    for (int d = 0; d < dim; ++d) descriptors(i, d) = static_cast<float>(random.Normal());
  }
  return UnitRows(descriptors);
}

// Two images: image 0 observes points 10..13 (descriptors 0..3), image 1 points 20..21
// (descriptors 4..5), with the observations interleaved as a map builder might join them.
Scene TwoImageScene(const DescriptorMatrix& descriptors) {
  Scene scene;
  scene.images.resize(2);
  scene.points.resize(22, Eigen::Vector3d::Zero());
  const std::vector<uint32_t> images = {0, 1, 0, 0, 1, 0};
  const std::vector<uint32_t> points = {10, 20, 11, 12, 21, 13};
  const std::vector<int> rows = {0, 4, 1, 2, 5, 3};
  scene.observation_descriptors.resize(6, descriptors.cols());
  for (size_t i = 0; i < images.size(); ++i) {
    scene.observation_image_indices.push_back(images[i]);
    scene.observation_point_indices.push_back(points[i]);
    // Any norm: the matcher normalizes once.
    scene.observation_descriptors.row(i) = 3.0f * descriptors.row(rows[i]);
  }
  return scene;
}

TEST(NearestNeighborMatcher, MatchesEachQueryToItsObservationInTheRightImage) {
  const DescriptorMatrix descriptors = RandomUnitRows(6, 32, 1);
  const NearestNeighborMatcher matcher(TwoImageScene(descriptors));
  ASSERT_FALSE(matcher.empty());
  // Query rows: descriptor 2 (point 12), descriptor 5 (point 21), descriptor 0 (point 10).
  DescriptorMatrix query(3, 32);
  query << descriptors.row(2), descriptors.row(5), descriptors.row(0);
  const CandidateMatches in_image0 = matcher.Match(query, 0, {});
  EXPECT_THAT(in_image0.keypoints, ElementsAre(0, 2));
  EXPECT_THAT(in_image0.point_indices, ElementsAre(12, 10));
  const CandidateMatches in_image1 = matcher.Match(query, 1, {});
  EXPECT_THAT(in_image1.keypoints, ElementsAre(1));
  EXPECT_THAT(in_image1.point_indices, ElementsAre(21));
}

TEST(NearestNeighborMatcher, RatioTestRejectsAQueryBetweenTwoObservations) {
  const DescriptorMatrix descriptors = RandomUnitRows(6, 32, 2);
  const NearestNeighborMatcher matcher(TwoImageScene(descriptors));
  // Halfway between points 10 and 11: the best and second distances are equal.
  DescriptorMatrix query = UnitRows(descriptors.row(0) + descriptors.row(1));
  EXPECT_THAT(matcher.Match(query, 0, {.ratio = 0.9, .mutual = false}).keypoints, IsEmpty());
  // Slightly closer to point 11: accepted only without the ratio test's margin.
  query = UnitRows(0.49f * descriptors.row(0) + 0.51f * descriptors.row(1));
  EXPECT_THAT(matcher.Match(query, 0, {.ratio = 0.9, .mutual = false}).keypoints, IsEmpty());
  EXPECT_THAT(matcher.Match(query, 0, {.ratio = 1.0, .mutual = false}).point_indices,
              ElementsAre(11));
}

TEST(NearestNeighborMatcher, MutualCheckKeepsOnlyTheObservationsBestQuery) {
  const DescriptorMatrix descriptors = RandomUnitRows(6, 32, 3);
  const NearestNeighborMatcher matcher(TwoImageScene(descriptors));
  // Two queries near point 13; the second is nearer, so only it is mutual.
  DescriptorMatrix query(2, 32);
  query.row(0) = UnitRows(descriptors.row(3) + 0.3f * descriptors.row(0));
  query.row(1) = UnitRows(descriptors.row(3) + 0.1f * descriptors.row(0));
  EXPECT_THAT(matcher.Match(query, 0, {.ratio = 1.0, .mutual = true}).keypoints, ElementsAre(1));
  EXPECT_THAT(matcher.Match(query, 0, {.ratio = 1.0, .mutual = false}).keypoints,
              ElementsAre(0, 1));
}

// Rows standing for points, several per point: the ratio test weighs the best row against the
// best row of another point, so a query near two rows of one point (two views of it) is not
// rejected as ambiguous.
TEST(NearestNeighborMatcher, RatioTestComparesOtherPointsNotOtherRowsOfOnePoint) {
  const DescriptorMatrix descriptors = RandomUnitRows(3, 32, 8);
  DescriptorMatrix rows(3, 32);
  rows << UnitRows(descriptors.row(0) + 0.05f * descriptors.row(2)),
      UnitRows(descriptors.row(0) - 0.05f * descriptors.row(2)), descriptors.row(1);
  const DescriptorMatrix query = descriptors.row(0);
  const NearestNeighborOptions options{.ratio = 0.8, .mutual = true};
  const std::vector<uint32_t> one_point_two_rows = {7, 7, 9};
  EXPECT_THAT(MatchNearestRows(query, rows, one_point_two_rows.data(), options).point_indices,
              ElementsAre(7));
  // Two points with those rows: now the query is ambiguous.
  const std::vector<uint32_t> two_points = {7, 8, 9};
  EXPECT_THAT(MatchNearestRows(query, rows, two_points.data(), options).keypoints, IsEmpty());
  // The best row of another point may come before or after the best row.
  const DescriptorMatrix reversed = rows.colwise().reverse();
  const std::vector<uint32_t> reversed_points = {9, 7, 7};
  EXPECT_THAT(MatchNearestRows(query, reversed, reversed_points.data(), options).point_indices,
              ElementsAre(7));
}

// Unit queries near random rows: a third far from theirs (noise 2), so that the ratio test and
// the mutual check each reject some.
DescriptorMatrix NoisyQueriesOf(const DescriptorMatrix& rows, int count, uint64_t seed) {
  Random random(seed);
  const DescriptorMatrix noise = RandomUnitRows(count, static_cast<int>(rows.cols()), seed + 1);
  DescriptorMatrix query(count, rows.cols());
  for (int q = 0; q < count; ++q) {
    const float noise_level = q % 3 == 0 ? 2.0f : 0.4f;
    query.row(q) =
        rows.row(static_cast<int64_t>(random.UniformInt(rows.rows()))) + noise_level * noise.row(q);
  }
  return UnitRows(query);
}

// The definition in double precision: each query's best row, kept where the best row of every
// other point is far enough behind and, with `mutual`, where no earlier query is as similar to that
// row and no query more similar.
CandidateMatches MatchByDefinition(const DescriptorMatrix& query, const DescriptorMatrix& rows,
                                   const std::vector<uint32_t>& row_points,
                                   const NearestNeighborOptions& options) {
  const Eigen::MatrixXd similarity = query.cast<double>() * rows.cast<double>().transpose();
  CandidateMatches matches;
  for (int64_t q = 0; q < similarity.rows(); ++q) {
    Eigen::Index best_row = 0;
    similarity.row(q).maxCoeff(&best_row);
    double second = -2;
    for (int64_t j = 0; j < rows.rows(); ++j) {
      if (row_points[j] != row_points[best_row]) second = std::max(second, similarity(q, j));
    }
    const double best_distance = 2 - 2 * similarity(q, best_row);
    if (second > -2 && best_distance >= options.ratio * options.ratio * (2 - 2 * second)) continue;
    Eigen::Index best_query = 0;
    similarity.col(best_row).maxCoeff(&best_query);
    if (options.mutual && best_query != q) continue;
    matches.keypoints.push_back(static_cast<int>(q));
    matches.point_indices.push_back(row_points[best_row]);
  }
  return matches;
}

// Enough queries and rows that the similarities are computed in several blocks of queries: the
// matches are the definition's, with and without each filter.
TEST(NearestNeighborMatcher, ManyQueriesMatchAsTheDefinitionSays) {
  const int num_rows = 2000;
  const DescriptorMatrix rows = RandomUnitRows(num_rows, 32, 11);
  std::vector<uint32_t> row_points(num_rows);
  for (int j = 0; j < num_rows; ++j) row_points[j] = static_cast<uint32_t>(j / 2);
  const DescriptorMatrix query = NoisyQueriesOf(rows, 700, 12);
  for (const NearestNeighborOptions options :
       {NearestNeighborOptions{.ratio = 0.9, .mutual = true},
        NearestNeighborOptions{.ratio = 0.8, .mutual = false},
        NearestNeighborOptions{.ratio = 1.0, .mutual = true}}) {
    const CandidateMatches expected = MatchByDefinition(query, rows, row_points, options);
    const CandidateMatches matches = MatchNearestRows(query, rows, row_points.data(), options);
    EXPECT_EQ(matches.keypoints, expected.keypoints) << options.ratio << " " << options.mutual;
    EXPECT_EQ(matches.point_indices, expected.point_indices);
    // Neither filter may be idle on this data, or the comparison would not test it.
    EXPECT_GT(expected.size(), 100u);
    EXPECT_LT(expected.size(), 650u);
  }
  // Rows that do not lie side by side (the first 32 columns of wider rows) match the same way.
  DescriptorMatrix wider(num_rows, 40);
  wider.leftCols(32) = rows;
  wider.rightCols(8).setConstant(7.0f);
  const NearestNeighborOptions options{.ratio = 0.9, .mutual = true};
  const CandidateMatches strided =
      MatchNearestRows(query, wider.leftCols(32), row_points.data(), options);
  const CandidateMatches expected = MatchByDefinition(query, rows, row_points, options);
  EXPECT_EQ(strided.keypoints, expected.keypoints);
  EXPECT_EQ(strided.point_indices, expected.point_indices);
}

// Rows at 8 bits, as the map keeps its points' directions: each row's largest magnitude at 127.
std::vector<int8_t> CodesOf(const DescriptorMatrix& rows) {
  std::vector<int8_t> codes(rows.size());
  for (int64_t r = 0; r < rows.rows(); ++r) {
    const float largest = rows.row(r).cwiseAbs().maxCoeff();
    for (int64_t d = 0; d < rows.cols(); ++d) {
      codes[r * rows.cols() + d] = static_cast<int8_t>(std::lround(rows(r, d) / largest * 127));
    }
  }
  return codes;
}

// The unit rows that codes stand for.
DescriptorMatrix UnitRowsOfCodes(const std::vector<int8_t>& codes, int64_t dimension) {
  DescriptorMatrix rows(static_cast<int64_t>(codes.size()) / dimension, dimension);
  for (int64_t i = 0; i < rows.size(); ++i) rows.data()[i] = codes[i];
  return UnitRows(rows);
}

// Unit queries rounded to 7 bits as CountNearestRowMatches rounds them.
DescriptorMatrix QueriesAtSevenBits(const DescriptorMatrix& query) {
  const code_kernels::PackedQueryCodes packed =
      code_kernels::PackQueryCodes(query.data(), query.rows(), query.cols());
  DescriptorMatrix rounded(query.rows(), query.cols());
  for (int64_t q = 0; q < query.rows(); ++q) {
    const std::vector<int8_t> codes = code_kernels::QueryCodesOf(packed, q);
    for (int64_t d = 0; d < query.cols(); ++d) rounded(q, d) = codes[d];
  }
  return UnitRows(rounded);
}

RowCodeReader ReaderOf(const std::vector<int8_t>& codes, int64_t dimension) {
  return [&codes, dimension](int64_t first, int64_t count) {
    return std::vector<int8_t>(codes.begin() + first * dimension,
                               codes.begin() + (first + count) * dimension);
  };
}

std::vector<int> CountsOfEachSet(const DescriptorMatrix& query, const DescriptorMatrix& rows,
                                 const std::vector<std::vector<uint32_t>>& sets,
                                 const NearestNeighborOptions& options) {
  std::vector<int> counts;
  for (const std::vector<uint32_t>& set : sets) {
    DescriptorMatrix set_rows(static_cast<int64_t>(set.size()), rows.cols());
    for (size_t i = 0; i < set.size(); ++i)
      set_rows.row(static_cast<int64_t>(i)) = rows.row(set[i]);
    counts.push_back(
        static_cast<int>(MatchNearestRows(query, set_rows, set.data(), options).size()));
  }
  return counts;
}

// Sets of rows that overlap, as neighbouring images' points do: each set's count is what matching
// its rows alone gives to the queries at 7 bits, with each filter, on one thread and on several
// slices of the queries; and the rounding moves few of the full-precision queries' matches.
TEST(CountNearestRowMatchesTest, CountsWhatMatchingEachSetAloneFinds) {
  const int num_rows = 900;
  const int dimension = 32;
  const DescriptorMatrix rows = RandomUnitRows(num_rows, dimension, 21);
  const std::vector<int8_t> codes = CodesOf(rows);
  const DescriptorMatrix coded_rows = UnitRowsOfCodes(codes, dimension);
  Random random(22);
  std::vector<std::vector<uint32_t>> sets(7);
  for (size_t set = 0; set < sets.size(); ++set) {
    // Windows of rows that overlap their neighbours, thinned at random.
    for (uint32_t row = static_cast<uint32_t>(set) * 100; row < set * 100 + 300 && row < num_rows;
         ++row) {
      if (random.Uniform() < 0.7) sets[set].push_back(row);
    }
  }
  sets.push_back({});  // an image that sees none of the rows
  const DescriptorMatrix query = NoisyQueriesOf(rows, 400, 23);
  const DescriptorMatrix rounded_query = QueriesAtSevenBits(query);
  for (const NearestNeighborOptions options :
       {NearestNeighborOptions{.ratio = 0.9, .mutual = true},
        NearestNeighborOptions{.ratio = 0.8, .mutual = false},
        NearestNeighborOptions{.ratio = 1.0, .mutual = true}}) {
    const std::vector<int> expected = CountsOfEachSet(rounded_query, coded_rows, sets, options);
    for (const int threads : {1, 3}) {
      EXPECT_EQ(CountNearestRowMatches(query, num_rows, ReaderOf(codes, dimension), sets, options,
                                       threads),
                expected)
          << options.ratio << " " << options.mutual << " on " << threads << " threads";
    }
    // Every set but the empty one has matches, and the filters reject some.
    EXPECT_GT(*std::min_element(expected.begin(), expected.end() - 1), 10);
    EXPECT_EQ(expected.back(), 0);
    const std::vector<int> full_precision = CountsOfEachSet(query, rows, sets, options);
    for (size_t set = 0; set < sets.size(); ++set) {
      EXPECT_LE(std::abs(expected[set] - full_precision[set]), 2 + full_precision[set] / 50)
          << set << ": " << expected[set] << " against " << full_precision[set];
    }
  }
}

TEST(CountNearestRowMatchesTest, RejectsSetsOutOfOrderOrPastTheRows) {
  const std::vector<int8_t> codes = CodesOf(RandomUnitRows(5, 8, 31));
  const DescriptorMatrix query = RandomUnitRows(3, 8, 32);
  const NearestNeighborOptions options;
  EXPECT_EQ(
      CountNearestRowMatches(query, 5, ReaderOf(codes, 8), {{0, 2, 4}, {1}}, options, 1).size(),
      2u);
  for (const std::vector<uint32_t>& bad :
       std::vector<std::vector<uint32_t>>{{2, 1}, {1, 1}, {0, 5}}) {
    EXPECT_THROW(CountNearestRowMatches(query, 5, ReaderOf(codes, 8), {bad}, options, 1),
                 std::invalid_argument);
  }
  // A reader that gives fewer rows than asked for.
  const RowCodeReader short_reader = [&](int64_t first, int64_t count) {
    return std::vector<int8_t>(codes.begin() + first * 8, codes.begin() + (first + count - 1) * 8);
  };
  EXPECT_THROW(CountNearestRowMatches(query, 5, short_reader, {{0, 1}}, options, 1),
               std::invalid_argument);
}

TEST(NearestNeighborMatcher, EmptySceneAndBadImageIndex) {
  EXPECT_TRUE(NearestNeighborMatcher(Scene()).empty());
  const NearestNeighborMatcher matcher(TwoImageScene(RandomUnitRows(6, 8, 4)));
  EXPECT_THROW(matcher.Match(RandomUnitRows(1, 8, 5), 2, {}), std::invalid_argument);
  EXPECT_THROW(NearestNeighborOptions{.ratio = 0}.Check(), std::invalid_argument);
  EXPECT_THROW(NearestNeighborOptions{.ratio = 1.5}.Check(), std::invalid_argument);
}

TEST(SelectMatchesTest, KeepsTheChosenMatchesInTheGivenOrder) {
  CandidateMatches matches;
  matches.keypoints = {4, 7, 9};
  matches.point_indices = {40, 70, 90};
  matches.confidences = {0.4f, 0.7f, 0.9f};
  const CandidateMatches selected = SelectMatches(matches, {2, 0});
  EXPECT_EQ(selected.keypoints, (std::vector<int>{9, 4}));
  EXPECT_EQ(selected.point_indices, (std::vector<uint32_t>{90, 40}));
  EXPECT_EQ(selected.confidences, (std::vector<float>{0.9f, 0.4f}));
  matches.confidences.clear();
  const CandidateMatches without = SelectMatches(matches, {1});
  EXPECT_EQ(without.keypoints, (std::vector<int>{7}));
  EXPECT_TRUE(without.confidences.empty()) << "a matcher without confidences gets none";
}

}  // namespace
}  // namespace hscloc
