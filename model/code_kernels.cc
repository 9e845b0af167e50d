#include "model/code_kernels.h"

#ifdef __AVX2__
#include <immintrin.h>
#endif

// AVX-512 VNNI: vpdpbusd on 512-bit registers, and 32 of them.
#if defined(__AVX512VNNI__) && defined(__AVX512F__)
#define HSCLOC_CODE_KERNELS_AVX512_VNNI 1
#endif

#include <algorithm>
#include <cmath>
#include <cstring>

#include "util/check.h"

namespace hscloc::code_kernels {
namespace {

// Queries side by side in a panel: one vector register holds four dimensions of each. AVX-512's
// registers hold sixteen, and vpdpbusd multiplies twice as many codes per instruction at the rate
// of its 256-bit form (one per cycle on the Xeons measured, docs/decisions.md).
#ifdef HSCLOC_CODE_KERNELS_AVX512_VNNI
constexpr int64_t kGroup = 16;
#else
constexpr int64_t kGroup = 8;
#endif
constexpr int64_t kDimensionsPerStep = 4;
constexpr int64_t kPanelStepBytes = kGroup * kDimensionsPerStep;
// Rows by two panels. With AVX2's 16 registers, three rows (six accumulators): four left GCC
// spilling some of them to the stack, and ran at two thirds the rate. AVX-512's 32 registers hold
// six rows' twelve, which keep VNNI's one instruction per step busier through its latency (a
// tenth faster than three rows).
#ifdef HSCLOC_CODE_KERNELS_AVX512_VNNI
constexpr int kTileRows = 6;
#else
constexpr int kTileRows = 3;
#endif

int64_t Steps(int64_t dimension) {
  return (dimension + kDimensionsPerStep - 1) / kDimensionsPerStep;
}

// Where query `query`'s code of dimension d lies in its panels.
int64_t PanelPosition(int64_t dimension, int64_t query, int64_t d) {
  return query / kGroup * Steps(dimension) * kPanelStepBytes +
         d / kDimensionsPerStep * kPanelStepBytes + query % kGroup * kDimensionsPerStep +
         d % kDimensionsPerStep;
}

int32_t QueryCode(const PackedQueryCodes& queries, int64_t query, int64_t d) {
  return int32_t{queries.panels[PanelPosition(queries.dimension, query, d)]} - kQueryCodeOffset;
}

// Four codes of a row from dimension `first` on, as one 32-bit word, zero past the row's end (a
// row's last step may hold fewer than four).
int32_t CodeWord(const int8_t* row, int64_t first, int64_t dimension) {
  int32_t word = 0;
  std::memcpy(&word, row + first,
              static_cast<size_t>(std::min(kDimensionsPerStep, dimension - first)));
  return word;
}

#ifdef __AVX2__

// A panel's step of query codes, or a row's four codes broadcast, or a panel's 32-bit sums.
#ifdef HSCLOC_CODE_KERNELS_AVX512_VNNI
using CodeVector = __m512i;
inline CodeVector ZeroSums() { return _mm512_setzero_si512(); }
inline CodeVector LoadPanelStep(const uint8_t* step) { return _mm512_loadu_si512(step); }
inline CodeVector BroadcastWord(int32_t word) { return _mm512_set1_epi32(word); }
#else
using CodeVector = __m256i;
inline CodeVector ZeroSums() { return _mm256_setzero_si256(); }
inline CodeVector LoadPanelStep(const uint8_t* step) {
  return _mm256_loadu_si256(reinterpret_cast<const __m256i*>(step));
}
inline CodeVector BroadcastWord(int32_t word) { return _mm256_set1_epi32(word); }
#endif

// Each query's sum of four products (its offset codes, unsigned, by a row's four codes, signed)
// added to its 32-bit lane. VNNI does it in one instruction, vpdpbusd; plain AVX2 takes three:
// vpmaddubsw, whose 16-bit pair sums the query codes' 7 bits keep from saturating, so that both
// give the same exact sums, then vpmaddwd and an add.
inline CodeVector AddFourProducts(const CodeVector& sums, const CodeVector& query_codes,
                                  const CodeVector& row_codes) {
#ifdef HSCLOC_CODE_KERNELS_AVX512_VNNI
  return _mm512_dpbusd_epi32(sums, query_codes, row_codes);
#elif defined(__AVXVNNI__)
  return _mm256_dpbusd_avx_epi32(sums, query_codes, row_codes);
#else
  return _mm256_add_epi32(
      sums, _mm256_madd_epi16(_mm256_maddubs_epi16(query_codes, row_codes), _mm256_set1_epi16(1)));
#endif
}

// A panel's cosines with one row: (sums - row_offset) x row_inverse_norm x each query's inverse
// norm, in that order on every path.
inline void StoreSimilarities(const CodeVector& sums, int32_t row_offset, float row_inverse_norm,
                              const float* query_inverse_norms, float* out) {
#ifdef HSCLOC_CODE_KERNELS_AVX512_VNNI
  const __m512 dot = _mm512_cvtepi32_ps(_mm512_sub_epi32(sums, _mm512_set1_epi32(row_offset)));
  _mm512_storeu_ps(out, _mm512_mul_ps(_mm512_mul_ps(dot, _mm512_set1_ps(row_inverse_norm)),
                                      _mm512_loadu_ps(query_inverse_norms)));
#else
  const __m256 dot = _mm256_cvtepi32_ps(_mm256_sub_epi32(sums, _mm256_set1_epi32(row_offset)));
  _mm256_storeu_ps(out, _mm256_mul_ps(_mm256_mul_ps(dot, _mm256_set1_ps(row_inverse_norm)),
                                      _mm256_loadu_ps(query_inverse_norms)));
#endif
}

// One step of a tile: four codes of each of kRows rows, broadcast to every query of a panel,
// times the panel's offset query codes.
template <int kRows, int kPanels>
inline void CodeStep(const int32_t (&words)[kRows], const CodeVector (&queries)[kPanels],
                     CodeVector (&sums)[kRows][kPanels]) {
  for (int r = 0; r < kRows; ++r) {
    const CodeVector row_codes = BroadcastWord(words[r]);
    for (int p = 0; p < kPanels; ++p) {
      sums[r][p] = AddFourProducts(sums[r][p], queries[p], row_codes);
    }
  }
}

// Rows [0, kRows) of a tile against kPanels panels of queries. sums[r][p]: the row's products
// with panel p's offset query codes.
template <int kRows, int kPanels>
void CodeTile(const int8_t* codes, int64_t dimension, const uint8_t* panels, int64_t panel_bytes,
              CodeVector (&sums)[kRows][kPanels]) {
  for (int r = 0; r < kRows; ++r) {
    for (int p = 0; p < kPanels; ++p) sums[r][p] = ZeroSums();
  }
  const auto load_queries = [&](int64_t step, CodeVector(&queries)[kPanels]) {
    for (int p = 0; p < kPanels; ++p) {
      queries[p] = LoadPanelStep(panels + p * panel_bytes + step * kPanelStepBytes);
    }
  };
  const int64_t whole_steps = dimension / kDimensionsPerStep;
  for (int64_t step = 0; step < whole_steps; ++step) {
    CodeVector queries[kPanels];
    load_queries(step, queries);
    int32_t words[kRows];
    for (int r = 0; r < kRows; ++r) {
      std::memcpy(&words[r], codes + r * dimension + step * kDimensionsPerStep, sizeof(int32_t));
    }
    CodeStep<kRows, kPanels>(words, queries, sums);
  }
  if (whole_steps < Steps(dimension)) {
    CodeVector queries[kPanels];
    load_queries(whole_steps, queries);
    int32_t words[kRows];
    for (int r = 0; r < kRows; ++r) {
      words[r] = CodeWord(codes + r * dimension, whole_steps * kDimensionsPerStep, dimension);
    }
    CodeStep<kRows, kPanels>(words, queries, sums);
  }
}

template <int kRows, int kPanels>
void SimilarityTile(const int8_t* codes, const int32_t* row_offsets, const float* row_inverse_norms,
                    const PackedQueryCodes& queries, int64_t first_query, float* out) {
  const int64_t panel_bytes = Steps(queries.dimension) * kPanelStepBytes;
  CodeVector sums[kRows][kPanels];
  CodeTile<kRows, kPanels>(codes, queries.dimension,
                           queries.panels.data() + first_query / kGroup * panel_bytes, panel_bytes,
                           sums);
  for (int p = 0; p < kPanels; ++p) {
    const int64_t query = first_query + p * kGroup;
    for (int r = 0; r < kRows; ++r) {
      StoreSimilarities(sums[r][p], row_offsets[r], row_inverse_norms[r],
                        queries.inverse_norms.data() + query,
                        out + r * queries.padded_count + query);
    }
  }
}

// Tiles of kTileRows rows by up to two panels.
template <int kPanels>
void SimilarityRows(const int8_t* codes, const int32_t* row_offsets, const float* row_inverse_norms,
                    int64_t rows, const PackedQueryCodes& queries, int64_t first_query,
                    float* out) {
  const int64_t dimension = queries.dimension;
  int64_t row = 0;
  for (; row + kTileRows <= rows; row += kTileRows) {
    SimilarityTile<kTileRows, kPanels>(codes + row * dimension, row_offsets + row,
                                       row_inverse_norms + row, queries, first_query,
                                       out + row * queries.padded_count);
  }
  for (; row < rows; ++row) {
    SimilarityTile<1, kPanels>(codes + row * dimension, row_offsets + row, row_inverse_norms + row,
                               queries, first_query, out + row * queries.padded_count);
  }
}

#endif

}  // namespace

void PortableCodeSimilarities(const int8_t* codes, const float* row_inverse_norms, int64_t rows,
                              const PackedQueryCodes& queries, float* out) {
  for (int64_t row = 0; row < rows; ++row) {
    const int8_t* row_codes = codes + row * queries.dimension;
    for (int64_t query = 0; query < queries.padded_count; ++query) {
      int32_t dot = 0;
      for (int64_t d = 0; d < queries.dimension; ++d) {
        dot += int32_t{row_codes[d]} * QueryCode(queries, query, d);
      }
      out[row * queries.padded_count + query] =
          static_cast<float>(dot) * row_inverse_norms[row] * queries.inverse_norms[query];
    }
  }
}

int64_t QueryGroup() { return kGroup; }

PackedQueryCodes PackQueryCodes(const float* vectors, int64_t count, int64_t dimension) {
  THROW_CHECK_MSG(count >= 0 && dimension >= 1 && dimension <= kMaxDimension,
                  "query codes: {} vectors of dimension {} (1 to {})", count, dimension,
                  kMaxDimension);
  PackedQueryCodes packed;
  packed.count = count;
  packed.padded_count = (count + kGroup - 1) / kGroup * kGroup;
  packed.dimension = dimension;
  packed.panels.assign(packed.padded_count * Steps(dimension) * kDimensionsPerStep,
                       static_cast<uint8_t>(kQueryCodeOffset));
  packed.inverse_norms.assign(packed.padded_count, 0.0f);
  for (int64_t query = 0; query < count; ++query) {
    const float* vector = vectors + query * dimension;
    float largest = 0.0f;
    for (int64_t d = 0; d < dimension; ++d) largest = std::max(largest, std::abs(vector[d]));
    if (!(largest > 0.0f) || !std::isfinite(largest)) continue;  // a zero (or broken) vector
    int64_t squares = 0;
    for (int64_t d = 0; d < dimension; ++d) {
      const auto code = static_cast<int>(std::lround(vector[d] / largest * kLargestQueryCode));
      packed.panels[PanelPosition(dimension, query, d)] =
          static_cast<uint8_t>(code + kQueryCodeOffset);
      squares += int64_t{code} * code;
    }
    packed.inverse_norms[query] = static_cast<float>(1.0 / std::sqrt(static_cast<double>(squares)));
  }
  return packed;
}

std::vector<int8_t> QueryCodesOf(const PackedQueryCodes& queries, int64_t query) {
  THROW_CHECK_MSG(query >= 0 && query < queries.count, "query codes: vector {} of {}", query,
                  queries.count);
  std::vector<int8_t> codes(queries.dimension);
  for (int64_t d = 0; d < queries.dimension; ++d) {
    codes[d] = static_cast<int8_t>(QueryCode(queries, query, d));
  }
  return codes;
}

void InverseCodeNorms(const int8_t* codes, int64_t rows, int64_t dimension, float* out) {
  for (int64_t row = 0; row < rows; ++row) {
    // 32-bit sums, which the compiler vectorizes: within range up to kMaxDimension.
    int32_t squares = 0;
    for (int64_t d = 0; d < dimension; ++d) {
      const int32_t code = codes[row * dimension + d];
      squares += code * code;
    }
    out[row] =
        squares == 0 ? 0.0f : static_cast<float>(1.0 / std::sqrt(static_cast<double>(squares)));
  }
}

void CodeSimilarities(const int8_t* codes, const float* row_inverse_norms, int64_t rows,
                      const PackedQueryCodes& queries, float* out) {
#ifdef __AVX2__
  // The offset query codes add kQueryCodeOffset x the row's code sum to every product.
  thread_local std::vector<int32_t> row_offsets;
  row_offsets.resize(rows);
  for (int64_t row = 0; row < rows; ++row) {
    int32_t sum = 0;
    for (int64_t d = 0; d < queries.dimension; ++d) sum += codes[row * queries.dimension + d];
    row_offsets[row] = kQueryCodeOffset * sum;
  }
  // A chunk of rows at a time, its codes kept in the core's first cache while every pair of
  // panels passes over them from the second: streamed whole for each pair, the rows of a large
  // block came from memory once per pair.
  constexpr int64_t kChunkRows = 96;
  static_assert(kChunkRows % kTileRows == 0);
  for (int64_t first = 0; first < rows; first += kChunkRows) {
    const int64_t count = std::min(kChunkRows, rows - first);
    const int8_t* chunk = codes + first * queries.dimension;
    float* chunk_out = out + first * queries.padded_count;
    int64_t query = 0;
    for (; query + 2 * kGroup <= queries.padded_count; query += 2 * kGroup) {
      SimilarityRows<2>(chunk, row_offsets.data() + first, row_inverse_norms + first, count,
                        queries, query, chunk_out);
    }
    if (query < queries.padded_count) {
      SimilarityRows<1>(chunk, row_offsets.data() + first, row_inverse_norms + first, count,
                        queries, query, chunk_out);
    }
  }
#else
  PortableCodeSimilarities(codes, row_inverse_norms, rows, queries, out);
#endif
}

}  // namespace hscloc::code_kernels
