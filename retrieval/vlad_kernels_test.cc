#include "retrieval/vlad_kernels.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "util/random.h"
#include "util/testing.h"

namespace hscloc {
namespace {

using testing::NormalFloats;

// <row r, x> in double precision.
double ReferenceDot(const std::vector<float>& matrix, int64_t r, int64_t columns,
                    const std::vector<float>& x) {
  double dot = 0;
  for (int64_t c = 0; c < columns; ++c) dot += double{matrix[r * columns + c]} * x[c];
  return dot;
}

// matrix [rows x columns] times x through the half-precision copy.
std::vector<float> HalfPrecisionProduct(const std::vector<float>& matrix, int64_t rows,
                                        int64_t columns, const std::vector<float>& x) {
  const vlad_kernels::HalfPrecisionRows half =
      vlad_kernels::ToHalfPrecisionRows(matrix.data(), rows, columns);
  std::vector<float> out(rows);
  vlad_kernels::HalfPrecisionRowsTimes(half, x.data(), 0, rows, out.data());
  return out;
}

// Half precision keeps 11 significant bits: each product is off by at most 2^-11 of the row's
// largest entry times |x_c|, so a dot product by at most 2^-11 max|row| sum|x| (and far less on
// average, the rounding errors cancelling).
TEST(VladKernelsTest, HalfPrecisionRowsTimesFollowsTheFullPrecisionProduct) {
  Random random(1);
  for (const int64_t rows : {1, 3, 4, 9}) {
    for (const int64_t columns : {1, 15, 16, 17, 100, 256}) {
      // Rows of very different scales: each keeps its precision through its own scale.
      std::vector<float> matrix;
      for (int64_t r = 0; r < rows; ++r) {
        const std::vector<float> row =
            NormalFloats(columns, random, std::pow(10.0, 4 * (r % 3) - 4));
        matrix.insert(matrix.end(), row.begin(), row.end());
      }
      const std::vector<float> x = NormalFloats(columns, random);
      const std::vector<float> out = HalfPrecisionProduct(matrix, rows, columns, x);
      for (int64_t r = 0; r < rows; ++r) {
        double largest = 0;
        double x_sum = 0;
        for (int64_t c = 0; c < columns; ++c) {
          largest = std::max(largest, std::abs(double{matrix[r * columns + c]}));
          x_sum += std::abs(x[c]);
        }
        EXPECT_NEAR(out[r], ReferenceDot(matrix, r, columns, x), std::ldexp(largest * x_sum, -11))
            << rows << " x " << columns << ", row " << r;
      }
    }
  }
}

// Entries with at most 11 significant bits relative to their row's largest are stored exactly:
// the product is then the full-precision one up to float summation.
TEST(VladKernelsTest, RepresentableEntriesAreStoredExactly) {
  Random random(2);
  const int64_t rows = 6;
  const int64_t columns = 40;
  std::vector<float> matrix(rows * columns);
  for (int64_t r = 0; r < rows; ++r) {
    for (int64_t c = 0; c < columns; ++c) {
      const double integer = static_cast<double>(random.UniformInt(2048)) - 1024;
      matrix[r * columns + c] = static_cast<float>(std::ldexp(integer, static_cast<int>(r) - 3));
    }
    matrix[r * columns] = static_cast<float>(std::ldexp(1024.0, static_cast<int>(r) - 3));
  }
  const std::vector<float> x = NormalFloats(columns, random);
  const std::vector<float> out = HalfPrecisionProduct(matrix, rows, columns, x);
  for (int64_t r = 0; r < rows; ++r) {
    const double reference = ReferenceDot(matrix, r, columns, x);
    EXPECT_NEAR(out[r], reference, 1e-5 * std::ldexp(1024.0 * columns, static_cast<int>(r) - 3));
  }
}

// Narrowing rounds to nearest, ties to even: with the row's largest entry 1 (scale 1), the product
// with a unit vector reads one stored entry back. Between 0.75 and 1 half precision steps by 2^-11.
TEST(VladKernelsTest, NarrowingRoundsToNearestEven) {
  const float step = std::ldexp(1.0f, -11);
  const std::vector<float> row = {1.0f,
                                  0.75f + step / 2,                          // tie: down to even
                                  0.75f + 3 * step / 2,                      // tie: up to even
                                  0.75f + step / 2 + std::ldexp(1.0f, -20),  // above the tie: up
                                  -(0.75f + 3 * step / 2),                   // the sign kept
                                  0.75f + step / 4};                         // below: down
  const std::vector<float> expected = {
      1.0f, 0.75f, 0.75f + 2 * step, 0.75f + step, -(0.75f + 2 * step), 0.75f};
  const auto columns = static_cast<int64_t>(row.size());
  for (int64_t c = 0; c < columns; ++c) {
    std::vector<float> unit(columns, 0.0f);
    unit[c] = 1.0f;
    EXPECT_EQ(HalfPrecisionProduct(row, 1, columns, unit)[0], expected[c]) << "entry " << c;
  }
}

// A row's result is the same bits whichever range it is asked in (groups of rows or alone), so
// that splitting rows across threads cannot change an encoding; a zero row gives zero.
TEST(VladKernelsTest, ARowGivesTheSameBitsInAnyRange) {
  Random random(3);
  const int64_t rows = 11;
  const int64_t columns = 70;
  std::vector<float> matrix = NormalFloats(rows * columns, random);
  std::fill(matrix.begin() + 5 * columns, matrix.begin() + 6 * columns, 0.0f);
  const std::vector<float> x = NormalFloats(columns, random);
  const vlad_kernels::HalfPrecisionRows half =
      vlad_kernels::ToHalfPrecisionRows(matrix.data(), rows, columns);
  std::vector<float> all(rows);
  vlad_kernels::HalfPrecisionRowsTimes(half, x.data(), 0, rows, all.data());
  EXPECT_EQ(all[5], 0.0f);
  for (int64_t first = 0; first < rows; ++first) {
    for (int64_t end = first + 1; end <= rows; ++end) {
      std::vector<float> part(end - first);
      vlad_kernels::HalfPrecisionRowsTimes(half, x.data(), first, end, part.data());
      for (int64_t r = first; r < end; ++r) {
        EXPECT_EQ(part[r - first], all[r]) << "row " << r << " of [" << first << ", " << end << ")";
      }
    }
  }
}

// The nearest centroid by brute force in double precision; duplicated centroids tie, and the
// lower word wins.
TEST(VladKernelsTest, NearestWordsIsTheBruteForceNearestCentroid) {
  Random random(4);
  for (const int64_t count : {1, 15, 16, 33}) {
    for (const int64_t words : {1, 7, 8, 20}) {
      const int64_t dim = 24;
      std::vector<float> centroids = NormalFloats(words * dim, random);
      if (words > 3) std::copy_n(centroids.begin(), dim, centroids.begin() + 3 * dim);
      std::vector<float> half_squared_norms(words);
      for (int64_t w = 0; w < words; ++w) {
        double norm = 0;
        for (int64_t d = 0; d < dim; ++d)
          norm += double{centroids[w * dim + d]} * centroids[w * dim + d];
        half_squared_norms[w] = static_cast<float>(norm / 2);
      }
      std::vector<float> descriptors = NormalFloats(count * dim, random);
      // A descriptor on a duplicated centroid: words 0 and 3 tie.
      if (words > 3) std::copy_n(centroids.begin(), dim, descriptors.begin());
      std::vector<int32_t> nearest(count, -1);
      vlad_kernels::NearestWords(descriptors.data(), count, centroids.data(),
                                 half_squared_norms.data(), words, dim, nearest.data());
      for (int64_t i = 0; i < count; ++i) {
        int64_t best = 0;
        double best_distance = INFINITY;
        for (int64_t w = 0; w < words; ++w) {
          double distance = 0;
          for (int64_t d = 0; d < dim; ++d) {
            const double difference = double{descriptors[i * dim + d]} - centroids[w * dim + d];
            distance += difference * difference;
          }
          // Equal up to rounding: the first of them.
          if (distance < best_distance - 1e-4) {
            best = w;
            best_distance = distance;
          }
        }
        EXPECT_EQ(nearest[i], best) << count << " descriptors, " << words << " words, #" << i;
      }
    }
  }
}

}  // namespace
}  // namespace hscloc
