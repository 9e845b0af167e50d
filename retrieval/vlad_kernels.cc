// See vlad_kernels.h for why Eigen is renamed here: this file is compiled with its own -march,
// and its Eigen instantiations must not be merged with the baseline ones of other files (nor with
// model/dense_kernels.cc's, compiled without OpenMP).
#define Eigen HsclocVladKernelEigen
#include <Eigen/Core>
#undef Eigen

#include <algorithm>
#include <cmath>
#include <limits>

#include "retrieval/vlad_kernels.h"

namespace hscloc::vlad_kernels {
namespace {

namespace E = HsclocVladKernelEigen;
namespace ei = HsclocVladKernelEigen::internal;
using Packet = ei::packet_traits<float>::type;
constexpr int64_t kLanes = ei::packet_traits<float>::size;

// kLanes half-precision values widened to floats: one instruction where the CPU converts halves
// (AVX-512, or AVX with F16C), else one value at a time.
Packet LoadHalves(const uint16_t* values) {
#if defined(EIGEN_VECTORIZE_AVX512)
  return _mm512_cvtph_ps(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(values)));
#elif defined(EIGEN_VECTORIZE_AVX) && defined(__F16C__)
  return _mm256_cvtph_ps(_mm_loadu_si128(reinterpret_cast<const __m128i*>(values)));
#else
  const auto* halves = reinterpret_cast<const E::half*>(values);
  alignas(64) float widened[kLanes];
  for (int64_t lane = 0; lane < kLanes; ++lane) widened[lane] = static_cast<float>(halves[lane]);
  return ei::pload<Packet>(widened);
#endif
}

// kLanes floats narrowed to half precision, rounded to nearest even (the same rounding on every
// path): a whole projection converts as a map loads, 33 million values on the city's.
void StoreHalves(const Packet& values, uint16_t* out) {
#if defined(EIGEN_VECTORIZE_AVX512)
  _mm256_storeu_si256(reinterpret_cast<__m256i*>(out),
                      _mm512_cvtps_ph(values, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC));
#elif defined(EIGEN_VECTORIZE_AVX) && defined(__F16C__)
  _mm_storeu_si128(reinterpret_cast<__m128i*>(out),
                   _mm256_cvtps_ph(values, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC));
#else
  alignas(64) float narrowed[kLanes];
  ei::pstore(narrowed, values);
  for (int64_t lane = 0; lane < kLanes; ++lane) out[lane] = E::half(narrowed[lane]).x;
#endif
}

// <row k, x> for kRows consecutive rows of `columns` halves: one chain of multiply-adds per row
// over whole packets, then the tail padded into a packet of its own, so that a row gets the same
// bits in a group of rows or alone. Rows stream from memory side by side: four at once took a
// third less time than one after another, one core alone being short of the memory's bandwidth.
template <int kRows>
void HalfRowDots(const uint16_t* rows, int64_t columns, const float* x, float* dots) {
  Packet sums[kRows];
  for (int k = 0; k < kRows; ++k) sums[k] = ei::pset1<Packet>(0);
  int64_t c = 0;
  for (; c + kLanes <= columns; c += kLanes) {
    const Packet xs = ei::ploadu<Packet>(x + c);
    for (int k = 0; k < kRows; ++k) {
      sums[k] = ei::pmadd(LoadHalves(rows + k * columns + c), xs, sums[k]);
    }
  }
  if (c < columns) {
    alignas(64) float x_tail[kLanes] = {};
    std::copy(x + c, x + columns, x_tail);
    for (int k = 0; k < kRows; ++k) {
      alignas(64) uint16_t row_tail[kLanes] = {};
      std::copy(rows + k * columns + c, rows + (k + 1) * columns, row_tail);
      sums[k] = ei::pmadd(LoadHalves(row_tail), ei::pload<Packet>(x_tail), sums[k]);
    }
  }
  for (int k = 0; k < kRows; ++k) dots[k] = ei::predux(sums[k]);
}

// The scores <centroid, descriptor> of kWords consecutive words (rows of `dim` floats from
// `centroids`) for the kLanes transposed descriptors, each its own chain of multiply-adds.
template <int kWords>
void ScoreWords(const float* transposed, int64_t dim, const float* centroids, Packet* scores) {
  for (int w = 0; w < kWords; ++w) scores[w] = ei::pset1<Packet>(0);
  for (int64_t d = 0; d < dim; ++d) {
    const Packet values = ei::pload<Packet>(transposed + d * kLanes);
    for (int w = 0; w < kWords; ++w) {
      scores[w] = ei::pmadd(ei::pset1<Packet>(centroids[w * dim + d]), values, scores[w]);
    }
  }
}

}  // namespace

HalfPrecisionRows ToHalfPrecisionRows(const float* row_major, int64_t rows, int64_t columns) {
  HalfPrecisionRows matrix{rows, columns, std::vector<uint16_t>(rows * columns),
                           std::vector<float>(rows, 0.0f)};
  for (int64_t r = 0; r < rows; ++r) {
    const float* row = row_major + r * columns;
    uint16_t* halves = matrix.values.data() + r * columns;
    float largest = 0;
    for (int64_t c = 0; c < columns; ++c) largest = std::max(largest, std::abs(row[c]));
    matrix.scales[r] = largest;
    const Packet inverse = ei::pset1<Packet>(largest > 0 ? 1.0f / largest : 0.0f);
    int64_t c = 0;
    for (; c + kLanes <= columns; c += kLanes) {
      StoreHalves(ei::pmul(ei::ploadu<Packet>(row + c), inverse), halves + c);
    }
    if (c < columns) {
      alignas(64) float tail[kLanes] = {};
      alignas(64) uint16_t tail_halves[kLanes];
      std::copy(row + c, row + columns, tail);
      StoreHalves(ei::pmul(ei::pload<Packet>(tail), inverse), tail_halves);
      std::copy(tail_halves, tail_halves + (columns - c), halves + c);
    }
  }
  return matrix;
}

void HalfPrecisionRowsTimes(const HalfPrecisionRows& matrix, const float* x, int64_t first_row,
                            int64_t end_row, float* out) {
  const int64_t columns = matrix.columns;
  int64_t r = first_row;
  for (; r + 4 <= end_row; r += 4) {
    HalfRowDots<4>(matrix.values.data() + r * columns, columns, x, out + (r - first_row));
  }
  for (; r < end_row; ++r) {
    HalfRowDots<1>(matrix.values.data() + r * columns, columns, x, out + (r - first_row));
  }
  for (r = first_row; r < end_row; ++r) out[r - first_row] *= matrix.scales[r];
}

void NearestWords(const float* descriptors, int64_t count, const float* centroids,
                  const float* half_squared_norms, int64_t words, int64_t dim, int32_t* nearest) {
  // kLanes descriptors at a time, transposed to [dim][kLanes] so that one packet holds one
  // dimension of each: a word's score for all of them is a chain of dim multiply-adds, eight
  // words' chains at once.
  std::vector<float, E::aligned_allocator<float>> transposed(dim * kLanes);
  constexpr int kWordsAtOnce = 8;
  for (int64_t first = 0; first < count; first += kLanes) {
    const int64_t lanes = std::min(kLanes, count - first);
    for (int64_t d = 0; d < dim; ++d) {
      for (int64_t lane = 0; lane < kLanes; ++lane) {
        transposed[d * kLanes + lane] = lane < lanes ? descriptors[(first + lane) * dim + d] : 0;
      }
    }
    Packet best_score = ei::pset1<Packet>(-std::numeric_limits<float>::infinity());
    Packet best_word = ei::pset1<Packet>(0);
    // Words in increasing order, a later one taking over only when strictly better.
    const auto keep_better = [&](const Packet* scores, int64_t word, int64_t chunk) {
      for (int64_t w = 0; w < chunk; ++w) {
        const Packet score = ei::psub(scores[w], ei::pset1<Packet>(half_squared_norms[word + w]));
        const Packet better = ei::pcmp_lt(best_score, score);
        best_score = ei::pselect(better, score, best_score);
        best_word = ei::pselect(better, ei::pset1<Packet>(static_cast<float>(word + w)), best_word);
      }
    };
    Packet scores[kWordsAtOnce];
    int64_t word = 0;
    for (; word + kWordsAtOnce <= words; word += kWordsAtOnce) {
      ScoreWords<kWordsAtOnce>(transposed.data(), dim, centroids + word * dim, scores);
      keep_better(scores, word, kWordsAtOnce);
    }
    for (; word < words; ++word) {
      ScoreWords<1>(transposed.data(), dim, centroids + word * dim, scores);
      keep_better(scores, word, 1);
    }
    alignas(64) float chosen[kLanes];
    ei::pstore(chosen, best_word);
    for (int64_t lane = 0; lane < lanes; ++lane) {
      nearest[first + lane] = static_cast<int32_t>(chosen[lane]);
    }
  }
}

}  // namespace hscloc::vlad_kernels
