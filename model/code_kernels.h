// Cosine similarities between 8-bit descriptor codes, for nearest-neighbour matching over many
// stored rows (localization/nearest_neighbor_matcher.h): map points keep their mean descriptors at
// 8 bits (map/point_descriptors.h), and matching a query against them in integers reads a quarter
// of the bytes of their float rows and multiplies 32 values per instruction (VNNI's vpdpbusd; 64
// in AVX-512's registers) or instruction pair (AVX2's vpmaddubsw then vpmaddwd) where a float
// product multiplies 8 per fused multiply-add.
//
// Compiled for the build machine's instruction set, as model/dense_kernels.h is and for the same
// reason; without AVX2 a portable loop gives the same results. The integer dot products are exact,
// so every path gives the same bits.
#pragma once

#include <cstdint>
#include <vector>

namespace hscloc::code_kernels {

// The largest query code. The product's unsigned operand is a query code offset by
// kQueryCodeOffset (up to 127), and two products of it with row codes (up to 127 in magnitude)
// must sum within a 16-bit integer: 2 x 127 x 127 <= 32767.
inline constexpr int kLargestQueryCode = 63;
inline constexpr int kQueryCodeOffset = 64;
// The products and norms are summed in 32 bits: 127 x 127 x 65,536 < 2^31.
inline constexpr int64_t kMaxDimension = 65536;

// Query vectors at 7 bits for CodeSimilarities: each vector's values rounded to integers in
// [-kLargestQueryCode, kLargestQueryCode] at its own scale (its largest magnitude maps to the
// largest code), packed QueryGroup() vectors and four dimensions at a time.
struct PackedQueryCodes {
  int64_t count = 0;
  int64_t padded_count = 0;  // a multiple of QueryGroup(); the padding vectors are zero
  int64_t dimension = 0;
  // The codes plus kQueryCodeOffset, [padded_count / QueryGroup()][ceil(dimension / 4)]
  // [QueryGroup()][4]; code 0 past `dimension` and for the padding vectors.
  std::vector<uint8_t> panels;
  std::vector<float> inverse_norms;  // per vector (padded_count): 1 / its codes' norm, 0 if zero
};
int64_t QueryGroup();

// Throws std::invalid_argument for a negative count or a dimension outside [1, kMaxDimension].
PackedQueryCodes PackQueryCodes(const float* vectors, int64_t count, int64_t dimension);

// The codes of one query vector as PackQueryCodes rounds them, in dimension order.
std::vector<int8_t> QueryCodesOf(const PackedQueryCodes& queries, int64_t query);

// 1 / the norm of each of `rows` code rows of `dimension` (up to kMaxDimension) codes (0 for a
// zero row), from the exact integer sum of squares.
void InverseCodeNorms(const int8_t* codes, int64_t rows, int64_t dimension, float* out);

// out[r * queries.padded_count + q] = the cosine between code row r (codes[r * dimension ..],
// values in [-127, 127]) and query q: their exact integer dot product times row_inverse_norms[r],
// then times queries.inverse_norms[q]. Padding queries give 0. The dimension must be the queries'.
void CodeSimilarities(const int8_t* codes, const float* row_inverse_norms, int64_t rows,
                      const PackedQueryCodes& queries, float* out);
// CodeSimilarities one product at a time: what a machine without AVX2 runs, and the reference
// every machine's path equals to the bit.
void PortableCodeSimilarities(const int8_t* codes, const float* row_inverse_norms, int64_t rows,
                              const PackedQueryCodes& queries, float* out);

}  // namespace hscloc::code_kernels
