#include "model/code_kernels.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <vector>

#include "util/random.h"

namespace hscloc {
namespace {

std::vector<float> NormalVectors(int64_t count, int64_t dimension, uint64_t seed) {
  Random random(seed);
  std::vector<float> values(count * dimension);
  for (float& value : values) value = static_cast<float>(random.Normal());
  return values;
}

// Codes in [-127, 127], as the map stores its points' mean descriptors.
std::vector<int8_t> RandomCodes(int64_t rows, int64_t dimension, uint64_t seed) {
  Random random(seed);
  std::vector<int8_t> codes(rows * dimension);
  for (int8_t& code : codes)
    code = static_cast<int8_t>(static_cast<int>(random.UniformInt(255)) - 127);
  return codes;
}

double Cosine(const float* a, const float* b, int64_t dimension) {
  double dot = 0, a_squares = 0, b_squares = 0;
  for (int64_t d = 0; d < dimension; ++d) {
    dot += double{a[d]} * b[d];
    a_squares += double{a[d]} * a[d];
    b_squares += double{b[d]} * b[d];
  }
  return dot / std::sqrt(a_squares * b_squares);
}

// Each value rounds to the nearest code at the vector's scale, the largest magnitude to the
// largest code, and the codes keep the vector's direction.
TEST(CodeKernelsTest, QueryCodesRoundEachVectorAtItsOwnScale) {
  const int64_t dimension = 37;
  const std::vector<float> vectors = NormalVectors(5, dimension, 1);
  const code_kernels::PackedQueryCodes packed =
      code_kernels::PackQueryCodes(vectors.data(), 5, dimension);
  EXPECT_EQ(packed.padded_count % code_kernels::QueryGroup(), 0);
  for (int64_t query = 0; query < 5; ++query) {
    const float* vector = vectors.data() + query * dimension;
    float largest = 0;
    for (int64_t d = 0; d < dimension; ++d) largest = std::max(largest, std::abs(vector[d]));
    const std::vector<int8_t> codes = code_kernels::QueryCodesOf(packed, query);
    std::vector<float> as_floats(codes.begin(), codes.end());
    for (int64_t d = 0; d < dimension; ++d) {
      EXPECT_LE(std::abs(codes[d] - vector[d] / largest * code_kernels::kLargestQueryCode), 0.5f)
          << query << ", " << d;
    }
    const int64_t largest_at =
        std::max_element(vector, vector + dimension,
                         [](float a, float b) { return std::abs(a) < std::abs(b); }) -
        vector;
    EXPECT_EQ(std::abs(codes[largest_at]), code_kernels::kLargestQueryCode);
    EXPECT_GT(Cosine(as_floats.data(), vector, dimension), 0.999);
  }
  EXPECT_THROW(code_kernels::PackQueryCodes(vectors.data(), 1, 0), std::invalid_argument);
  const std::vector<float> too_long(code_kernels::kMaxDimension + 1, 1.0f);
  EXPECT_THROW(code_kernels::PackQueryCodes(too_long.data(), 1, code_kernels::kMaxDimension + 1),
               std::invalid_argument);
  EXPECT_THROW(code_kernels::QueryCodesOf(packed, 5), std::invalid_argument);
}

// Every shape's similarities are the cosines of the codes (the integer products are exact), on
// the machine's path and the portable one alike, to the bit; padding queries and zero vectors give
// zero.
TEST(CodeKernelsTest, SimilaritiesAreTheCodesCosinesOnEveryPath) {
  // Row counts under one tile and over one chunk of the kernel, neither a multiple of a tile.
  for (const int64_t rows : {11, 203}) {
    for (const int64_t dimension : {1, 4, 37, 64, 256}) {
      for (const int64_t num_queries : {1, 8, 13, 16, 35}) {
        std::vector<float> vectors = NormalVectors(num_queries, dimension, dimension + num_queries);
        std::fill_n(vectors.begin(), dimension, 0.0f);  // a zero query
        std::vector<int8_t> codes = RandomCodes(rows, dimension, 7 * dimension + num_queries);
        std::fill_n(codes.begin() + 2 * dimension, dimension, int8_t{0});     // a zero row
        std::fill_n(codes.begin() + 3 * dimension, dimension, int8_t{-127});  // the extreme codes
        std::fill_n(codes.begin() + 4 * dimension, dimension, int8_t{127});
        const code_kernels::PackedQueryCodes packed =
            code_kernels::PackQueryCodes(vectors.data(), num_queries, dimension);
        std::vector<float> inverse_norms(rows);
        code_kernels::InverseCodeNorms(codes.data(), rows, dimension, inverse_norms.data());
        std::vector<float> similarities(rows * packed.padded_count, -2.0f);
        std::vector<float> portable(rows * packed.padded_count, -3.0f);
        code_kernels::CodeSimilarities(codes.data(), inverse_norms.data(), rows, packed,
                                       similarities.data());
        code_kernels::PortableCodeSimilarities(codes.data(), inverse_norms.data(), rows, packed,
                                               portable.data());
        ASSERT_EQ(similarities, portable) << rows << " rows, " << dimension << " x " << num_queries;
        for (int64_t r = 0; r < rows; ++r) {
          const std::vector<float> row(codes.begin() + r * dimension,
                                       codes.begin() + (r + 1) * dimension);
          // Row 2 and, at small dimensions, some random ones are zero.
          const bool zero_row =
              std::all_of(row.begin(), row.end(), [](float code) { return code == 0.0f; });
          for (int64_t q = 0; q < packed.padded_count; ++q) {
            const float got = similarities[r * packed.padded_count + q];
            if (q >= num_queries || q == 0 || zero_row) {
              EXPECT_EQ(got, 0.0f) << r << ", " << q;
              continue;
            }
            const std::vector<int8_t> query_codes = code_kernels::QueryCodesOf(packed, q);
            const std::vector<float> query(query_codes.begin(), query_codes.end());
            EXPECT_NEAR(got, Cosine(row.data(), query.data(), dimension), 1e-6)
                << dimension << " x " << num_queries << ": " << r << ", " << q;
          }
        }
      }
    }
  }
}

}  // namespace
}  // namespace hscloc
