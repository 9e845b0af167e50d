// See dense_kernels.h for why Eigen is renamed here: this file is compiled with its own -march,
// and its Eigen instantiations must not be merged with the baseline ones of other files.
#define Eigen HsclocKernelEigen
#include <Eigen/Core>
#undef Eigen

#include <algorithm>
#include <array>
#include <cstring>
#include <limits>
#include <type_traits>
#include <utility>
#include <vector>

#include "model/dense_kernels.h"

namespace hscloc::dense_kernels {
namespace {

namespace E = HsclocKernelEigen;
namespace ei = HsclocKernelEigen::internal;
using RowMajorMatrix = E::Matrix<float, E::Dynamic, E::Dynamic, E::RowMajor>;
using ConstMatrixMap = E::Map<const RowMajorMatrix>;
using Packet = ei::packet_traits<float>::type;
constexpr int64_t kLanes = ei::packet_traits<float>::size;

// Element-wise work runs on whole packets only, the tail padded into a packet of its own. Eigen's
// array expressions instead peel a scalar head until the data is aligned, and scalar exp() rounds
// differently from the vector one: a value's result would depend on where its row sits in memory,
// and one query could get different confidences from one call to the next.
template <typename PacketOp>
void ForEachPacket(const float* in, int64_t count, float* out, const PacketOp& op) {
  int64_t i = 0;
  for (; i + kLanes <= count; i += kLanes) ei::pstoreu(out + i, op(ei::ploadu<Packet>(in + i)));
  if (i < count) {
    alignas(64) float tail[kLanes] = {};
    std::copy(in + i, in + count, tail);
    ei::pstore(tail, op(ei::pload<Packet>(tail)));
    std::copy(tail, tail + (count - i), out + i);
  }
}

// a * 2^exponent for an exponent of a normal float ([-126, 127]), from its exponent bits. A
// template, so that the packet type is deduced: named as a template argument, its vector
// attributes would be dropped with a warning.
template <typename PacketType>
PacketType TimesPowerOfTwo(const PacketType& a, const PacketType& exponent) {
#ifdef __AVX512F__
  // One instruction for the four of building the power from its bits and multiplying; a product
  // by a power of two rounds once either way, so the bits are the same.
  if constexpr (std::is_same_v<PacketType, __m512>) return _mm512_scalef_ps(a, exponent);
#endif
  return ei::pldexp_fast_impl<PacketType>::run(a, exponent);
}

// exp(x) for x <= 0, the argument of every exponential here (ELU's negative side, a softmax's
// logits less their largest). Eigen's pexp with its 2^m built from the exponent bits
// (TimesPowerOfTwo) in place of its general ldexp, which also handles the subnormal results of x <
// -87.3: for x >= -87.3 the same bits, for x below it 2^-126 (1.2e-38) where pexp gives less. No
// ELU tells them apart, nor a softmax sum, whose largest term is 1. A third faster on an ELU over
// random values (AVX2).
Packet ExpOfNonPositive(const Packet& argument) {
  // ln(2^-126): the smallest exponent whose power of two is a normal float.
  const Packet x = ei::pmax(argument, ei::pset1<Packet>(-87.33654f));
  const Packet m =
      ei::pfloor(ei::pmadd(x, ei::pset1<Packet>(1.44269504088896341f), ei::pset1<Packet>(0.5f)));
  // r = x - m ln 2, ln 2 in two parts (Cephes).
  Packet r = ei::pmadd(m, ei::pset1<Packet>(-0.693359375f), x);
  r = ei::pmadd(m, ei::pset1<Packet>(2.12194440e-4f), r);
  const Packet r2 = ei::pmul(r, r);
  const Packet r3 = ei::pmul(r2, r);
  Packet y = ei::pmadd(ei::pset1<Packet>(1.9875691500e-4f), r, ei::pset1<Packet>(1.3981999507e-3f));
  Packet y1 =
      ei::pmadd(ei::pset1<Packet>(4.1665795894e-2f), r, ei::pset1<Packet>(1.6666665459e-1f));
  const Packet y2 = ei::padd(r, ei::pset1<Packet>(1.0f));
  y = ei::pmadd(y, r, ei::pset1<Packet>(8.3334519073e-3f));
  y1 = ei::pmadd(y1, r, ei::pset1<Packet>(5.0000001201e-1f));
  y = ei::pmadd(y, r3, y1);
  y = ei::pmadd(y, r2, y2);
  return TimesPowerOfTwo(y, m);
}

// ELU as max(x, 0) + exp(min(x, 0)) - 1, branch-free.
Packet Elu(const Packet& x) {
  const Packet zero = ei::pzero(x);
  return ei::padd(ei::pmax(x, zero),
                  ei::psub(ExpOfNonPositive(ei::pmin(x, zero)), ei::pset1<Packet>(1)));
}

}  // namespace

namespace {

// The matrix product's register tile: kTileRows input rows by one panel of two packets of output
// features, 2 kTileRows accumulators (24 of AVX-512's 32 registers; 12 of AVX2's 16), so that
// each weight packet loaded serves kTileRows fused multiply-adds and each broadcast input two.
constexpr int64_t kPanelWidth = 2 * kLanes;
constexpr int kTileRows = kLanes >= 16 ? 12 : 6;

// Rows [0, rows) of one tile (rows <= kTileRows, a compile-time count so the accumulators stay
// in registers) against one panel and its bias (kPanelWidth floats, aligned, zero past `columns`),
// into out[rows x columns] with row stride out_stride.
template <int rows>
void ProductTile(const float* in, int64_t in_features, const float* panel, const float* panel_bias,
                 int64_t columns, bool elu, float* out, int64_t out_stride) {
  // Every loop over the tile's rows is unrolled: a loop left rolled makes the compiler keep the
  // accumulators in memory, zeroed by a call to memset on every tile.
  Packet low[rows];
  Packet high[rows];
#pragma GCC unroll 16
  for (int r = 0; r < rows; ++r) low[r] = high[r] = ei::pset1<Packet>(0);
  for (int64_t k = 0; k < in_features; ++k) {
    const Packet weight_low = ei::ploadu<Packet>(panel + k * kPanelWidth);
    const Packet weight_high = ei::ploadu<Packet>(panel + k * kPanelWidth + kLanes);
    for (int r = 0; r < rows; ++r) {
      const Packet x = ei::pset1<Packet>(in[r * in_features + k]);
      low[r] = ei::pmadd(x, weight_low, low[r]);
      high[r] = ei::pmadd(x, weight_high, high[r]);
    }
  }
  const Packet bias_low = ei::pload<Packet>(panel_bias);
  const Packet bias_high = ei::pload<Packet>(panel_bias + kLanes);
  alignas(64) float tail[kPanelWidth];
#pragma GCC unroll 16
  for (int r = 0; r < rows; ++r) {
    Packet first = ei::padd(low[r], bias_low);
    Packet second = ei::padd(high[r], bias_high);
    if (elu) {
      first = Elu(first);
      second = Elu(second);
    }
    float* out_row = out + r * out_stride;
    if (columns == kPanelWidth) {
      ei::pstoreu(out_row, first);
      ei::pstoreu(out_row + kLanes, second);
    } else {
      ei::pstore(tail, first);
      ei::pstore(tail + kLanes, second);
      std::copy(tail, tail + columns, out_row);
    }
  }
}

using ProductTileFunction = void (*)(const float*, int64_t, const float*, const float*, int64_t,
                                     bool, float*, int64_t);

template <int... counts>
constexpr std::array<ProductTileFunction, sizeof...(counts)> ProductTilesByRows(
    std::integer_sequence<int, counts...>) {
  return {&ProductTile<counts + 1>...};
}

// ProductTile for 1 .. kTileRows rows, indexed by rows - 1.
constexpr auto kProductTiles = ProductTilesByRows(std::make_integer_sequence<int, kTileRows>{});

}  // namespace

int64_t PanelWidth() { return kPanelWidth; }

PackedMatrix PackMatrix(const float* weight, int64_t out_features, int64_t in_features) {
  PackedMatrix packed{out_features, in_features, {}};
  const int64_t panels = (out_features + kPanelWidth - 1) / kPanelWidth;
  packed.panels.assign(panels * in_features * kPanelWidth, 0.0f);
  for (int64_t feature = 0; feature < out_features; ++feature) {
    float* column = packed.panels.data() + feature / kPanelWidth * in_features * kPanelWidth +
                    feature % kPanelWidth;
    for (int64_t k = 0; k < in_features; ++k)
      column[k * kPanelWidth] = weight[feature * in_features + k];
  }
  return packed;
}

// Panel by panel, so that a panel ([in_features, kPanelWidth], 64 KB at 512 features) stays in
// the core's cache while every row tile passes over it.
void Linear(const float* in, int64_t rows, const PackedMatrix& weight, const float* bias, bool elu,
            float* out) {
  const int64_t in_features = weight.in_features;
  const int64_t out_features = weight.out_features;
  for (int64_t first_column = 0; first_column < out_features; first_column += kPanelWidth) {
    const float* panel = weight.panels.data() + first_column * in_features;
    const int64_t columns = std::min(kPanelWidth, out_features - first_column);
    alignas(64) float panel_bias[kPanelWidth] = {};
    std::copy(bias + first_column, bias + first_column + columns, panel_bias);
    for (int64_t first_row = 0; first_row < rows; first_row += kTileRows) {
      const int64_t tile_rows = std::min<int64_t>(kTileRows, rows - first_row);
      kProductTiles[tile_rows - 1](in + first_row * in_features, in_features, panel, panel_bias,
                                   columns, elu, out + first_row * out_features + first_column,
                                   out_features);
    }
  }
}

void ModulateElu(const float* source, const int64_t* source_rows, const float* gamma,
                 const float* beta, const int32_t* modulation_rows, int64_t rows, int64_t columns,
                 float* out) {
  for (int64_t row = 0; row < rows; ++row) {
    const float* source_row = source + (source_rows != nullptr ? source_rows[row] : row) * columns;
    const float* gamma_row = gamma + int64_t{modulation_rows[row]} * columns;
    const float* beta_row = beta + int64_t{modulation_rows[row]} * columns;
    float* out_row = out + row * columns;
    if (source_rows != nullptr && row + 1 < rows) {
      // Gathered rows are scattered over the source: the next one is fetched while this one is
      // modulated.
      const char* next_row = reinterpret_cast<const char*>(source + source_rows[row + 1] * columns);
      for (int64_t byte = 0; byte < columns * int64_t{sizeof(float)}; byte += 64) {
        __builtin_prefetch(next_row + byte);
      }
    }
    int64_t column = 0;
    for (; column + kLanes <= columns; column += kLanes) {
      ei::pstoreu(out_row + column, Elu(ei::pmadd(ei::ploadu<Packet>(gamma_row + column),
                                                  ei::ploadu<Packet>(source_row + column),
                                                  ei::ploadu<Packet>(beta_row + column))));
    }
    for (; column < columns; ++column) {
      alignas(64) float lane[kLanes] = {};
      lane[0] = gamma_row[column] * source_row[column] + beta_row[column];
      ei::pstore(lane, Elu(ei::pload<Packet>(lane)));
      out_row[column] = lane[0];
    }
  }
}

void EluInPlace(float* values, int64_t count) { ForEachPacket(values, count, values, Elu); }

void NodeLogits(const float* projected, int64_t num_inputs, int64_t dim, const float* node_rows,
                int64_t num_children, int64_t out_columns, float* out) {
  using StridedMap = E::Map<const RowMajorMatrix, 0, E::OuterStride<>>;
  const ConstMatrixMap input(projected, num_inputs, dim);
  const StridedMap weights(node_rows, num_children, dim, E::OuterStride<>(dim + 1));
  const E::Map<const E::RowVectorXf, 0, E::InnerStride<>> biases(node_rows + dim, num_children,
                                                                 E::InnerStride<>(dim + 1));
  E::Map<RowMajorMatrix, 0, E::OuterStride<>> output(out, num_inputs, num_children,
                                                     E::OuterStride<>(out_columns));
  output.noalias() = input * weights.transpose();
  output.rowwise() += biases;
  for (int64_t input_row = 0; input_row < num_inputs; ++input_row) {
    std::fill(out + input_row * out_columns + num_children, out + (input_row + 1) * out_columns,
              -std::numeric_limits<float>::infinity());
  }
}

namespace {

// The scores <projected, w_p> + b_p of kPoints points at once, each with its own chain of fused
// multiply-adds (the bias first, then the dimensions in order): eight independent chains keep both
// FMA units busy through their latency, where four chains left half of them idle.
template <int kPoints>
void ScoresOfPoints(const float* transposed, int64_t dim, const float* rows, int64_t width,
                    Packet* sums) {
  for (int p = 0; p < kPoints; ++p) sums[p] = ei::pset1<Packet>(rows[p * width + dim]);
  for (int64_t d = 0; d < dim; ++d) {
    const Packet x = ei::pload<Packet>(transposed + d * kLanes);
    for (int p = 0; p < kPoints; ++p) {
      sums[p] = ei::pmadd(ei::pset1<Packet>(rows[p * width + d]), x, sums[p]);
    }
  }
}

// take(sums, count) for the scores of points [begin, end), eight, four, then one at a time.
template <typename Take>
void ScoreSegment(const float* transposed, int64_t dim, const float* point_rows, int64_t begin,
                  int64_t end, const Take& take) {
  const int64_t width = dim + 1;
  Packet sums[8];
  int64_t point = begin;
  for (; point + 8 <= end; point += 8) {
    ScoresOfPoints<8>(transposed, dim, point_rows + point * width, width, sums);
    take(sums, 8);
  }
  for (; point + 4 <= end; point += 4) {
    ScoresOfPoints<4>(transposed, dim, point_rows + point * width, width, sums);
    take(sums, 4);
  }
  for (; point < end; ++point) {
    ScoresOfPoints<1>(transposed, dim, point_rows + point * width, width, sums);
    take(sums, 1);
  }
}

// The pooled logits' common frame: kLanes inputs at a time, transposed to [dim][kLanes] so that one
// packet holds one dimension of each (a point's score for all of them is a chain of dim fused
// multiply-adds). score_chunk(transposed) runs once per packet of inputs, then
// pool_segment(transposed, begin, end) gives each lane's pooled score of a segment's rows, and each
// child keeps the largest of its segments'.
template <typename ScoreChunk, typename PoolSegment>
void PooledLogits(const float* projected, int64_t num_inputs, int64_t dim,
                  const uint32_t* segment_starts, const uint8_t* segment_groups,
                  int64_t num_segments, int64_t out_columns, float* out,
                  const ScoreChunk& score_chunk, const PoolSegment& pool_segment) {
  thread_local std::vector<float, E::aligned_allocator<float>> transposed;
  transposed.resize(dim * kLanes);
  alignas(64) float pooled_lanes[kLanes];
  for (int64_t first = 0; first < num_inputs; first += kLanes) {
    const int64_t lanes = std::min<int64_t>(kLanes, num_inputs - first);
    for (int64_t d = 0; d < dim; ++d) {
      for (int64_t lane = 0; lane < kLanes; ++lane) {
        transposed[d * kLanes + lane] = lane < lanes ? projected[(first + lane) * dim + d] : 0.0f;
      }
    }
    score_chunk(transposed.data());
    for (int64_t k = 0; k < num_segments; ++k) {
      ei::pstore(pooled_lanes,
                 pool_segment(transposed.data(), segment_starts[k], segment_starts[k + 1]));
      for (int64_t lane = 0; lane < lanes; ++lane) {
        float& logit = out[(first + lane) * out_columns + segment_groups[k]];
        logit = std::max(logit, pooled_lanes[lane]);
      }
    }
  }
}

}  // namespace

void PooledMaxLogits(const float* projected, int64_t num_inputs, int64_t dim,
                     const float* point_rows, const uint32_t* segment_starts,
                     const uint8_t* segment_groups, int64_t num_segments, int64_t out_columns,
                     float* out) {
  const auto best_score = [&](const float* transposed, int64_t begin, int64_t end) {
    Packet best = ei::pset1<Packet>(-std::numeric_limits<float>::infinity());
    ScoreSegment(transposed, dim, point_rows, begin, end, [&](const Packet* sums, int count) {
      for (int p = 0; p < count; ++p) best = ei::pmax(best, sums[p]);
    });
    return best;
  };
  PooledLogits(
      projected, num_inputs, dim, segment_starts, segment_groups, num_segments, out_columns, out,
      [](const float*) {}, best_score);
}

void BestPointLogSumExpLogits(const float* projected, int64_t num_inputs, int64_t dim,
                              const float* point_rows, const uint32_t* segment_starts,
                              const uint8_t* segment_groups, int64_t num_segments,
                              int64_t out_columns, float* out) {
  // A point has a few rows: the whole chunk is scored eight rows at a time across the points'
  // bounds, which keeps the fused multiply-add chains as busy as the maximum's; each point then
  // reduces its scores.
  thread_local std::vector<float, E::aligned_allocator<float>> scores;
  const int64_t chunk_begin = segment_starts[0];
  scores.resize(static_cast<size_t>(segment_starts[num_segments] - chunk_begin) * kLanes);
  const auto score_chunk = [&](const float* transposed) {
    float* next = scores.data();
    ScoreSegment(transposed, dim, point_rows, chunk_begin, segment_starts[num_segments],
                 [&](const Packet* sums, int count) {
                   for (int p = 0; p < count; ++p, next += kLanes) ei::pstore(next, sums[p]);
                 });
  };
  const auto log_sum_exp = [&](const float*, int64_t begin, int64_t end) {
    const float* first = scores.data() + (begin - chunk_begin) * kLanes;
    const float* last = scores.data() + (end - chunk_begin) * kLanes;
    Packet best = ei::pset1<Packet>(-std::numeric_limits<float>::infinity());
    for (const float* score = first; score != last; score += kLanes) {
      best = ei::pmax(best, ei::pload<Packet>(score));
    }
    Packet sum = ei::pzero(best);
    for (const float* score = first; score != last; score += kLanes) {
      sum = ei::padd(sum, ExpOfNonPositive(ei::psub(ei::pload<Packet>(score), best)));
    }
    return ei::padd(best, ei::plog(sum));
  };
  PooledLogits(projected, num_inputs, dim, segment_starts, segment_groups, num_segments,
               out_columns, out, score_chunk, log_sum_exp);
}

namespace {

// The row's length without its trailing -inf values (children a parent lacks, or none of whose
// points the image sees): a packet at a time from the end, then value by value.
int64_t LiveColumns(const float* row, int64_t columns) {
  const Packet missing = ei::pset1<Packet>(-std::numeric_limits<float>::infinity());
  int64_t live = columns;
  while (live >= kLanes) {
    const Packet is_missing = ei::pcmp_eq(ei::ploadu<Packet>(row + live - kLanes), missing);
    if (ei::predux_any(ei::pandnot(ei::ptrue(is_missing), is_missing))) break;
    live -= kLanes;
  }
  while (live > 0 && row[live - 1] == -std::numeric_limits<float>::infinity()) --live;
  return live;
}

// The largest of values[0, count), count > 0: a maximum is exact, so the order does not matter.
float MaxOf(const float* values, int64_t count) {
  Packet maxima = ei::pset1<Packet>(values[0]);
  int64_t i = 0;
  for (; i + kLanes <= count; i += kLanes)
    maxima = ei::pmax(maxima, ei::ploadu<Packet>(values + i));
  float max = ei::predux_max(maxima);
  for (; i < count; ++i) max = std::max(max, values[i]);
  return max;
}

}  // namespace

void UpdateBestTwo(const float* values, int64_t count, int32_t index, float* best, float* second,
                   int32_t* best_index) {
  // The indices are blended as float lanes holding their bits: a blend moves bits unchanged.
  static_assert(sizeof(int32_t) == sizeof(float));
  float index_bits;
  std::memcpy(&index_bits, &index, sizeof(index));
  const Packet index_packet = ei::pset1<Packet>(index_bits);
  float* index_lanes = reinterpret_cast<float*>(best_index);
  int64_t i = 0;
  for (; i + kLanes <= count; i += kLanes) {
    const Packet value = ei::ploadu<Packet>(values + i);
    const Packet old_best = ei::ploadu<Packet>(best + i);
    const Packet above = ei::pcmp_lt(old_best, value);
    ei::pstoreu(second + i,
                ei::pselect(above, old_best, ei::pmax(ei::ploadu<Packet>(second + i), value)));
    ei::pstoreu(best + i, ei::pselect(above, value, old_best));
    ei::pstoreu(index_lanes + i,
                ei::pselect(above, index_packet, ei::ploadu<Packet>(index_lanes + i)));
  }
  for (; i < count; ++i) {
    const bool above = values[i] > best[i];
    second[i] = above ? best[i] : std::max(second[i], values[i]);
    best_index[i] = above ? index : best_index[i];
    best[i] = above ? values[i] : best[i];
  }
}

int64_t FirstArgMax(const float* values, int64_t count) {
  const float largest = MaxOf(values, count);
  // A packet at a time to the first that holds it, then a lane at a time within it.
  const Packet largest_packet = ei::pset1<Packet>(largest);
  int64_t i = 0;
  for (; i + kLanes <= count; i += kLanes) {
    if (ei::predux_any(ei::pcmp_eq(ei::ploadu<Packet>(values + i), largest_packet))) break;
  }
  return std::find(values + i, values + count, largest) - values;
}

void SoftmaxNormalizers(const float* logits, int64_t rows, int64_t columns,
                        SoftmaxNormalizer* normalizers) {
  for (int64_t row_index = 0; row_index < rows; ++row_index) {
    const float* row = logits + row_index * columns;
    const int64_t live = LiveColumns(row, columns);
    if (live == 0) {
      // Every value -inf: exp(-inf - -inf) is NaN on every column, as over the whole row.
      normalizers[row_index] = {-std::numeric_limits<float>::infinity(),
                                std::numeric_limits<float>::quiet_NaN()};
      continue;
    }
    const float largest = MaxOf(row, live);
    const Packet shift = ei::pset1<Packet>(largest);
    // A fixed summation order: packets from the row's start, then the lanes within a packet; the
    // last packet's lanes past `live` add zeros.
    Packet sums = ei::pset1<Packet>(0);
    int64_t i = 0;
    for (; i + kLanes <= live; i += kLanes) {
      sums = ei::padd(sums, ExpOfNonPositive(ei::psub(ei::ploadu<Packet>(row + i), shift)));
    }
    alignas(64) float tail[kLanes] = {};
    std::copy(row + i, row + live, tail);
    ei::pstore(tail, ExpOfNonPositive(ei::psub(ei::pload<Packet>(tail), shift)));
    std::fill(tail + (live - i), tail + kLanes, 0.0f);
    sums = ei::padd(sums, ei::pload<Packet>(tail));
    normalizers[row_index] = {largest, 1.f / ei::predux(sums)};
  }
}

float SoftmaxOf(float logit, const SoftmaxNormalizer& normalizer) {
  // The vector exponential, whose bits the normalizer's sum was taken with.
  alignas(64) float lanes[kLanes];
  ei::pstore(lanes, ei::pmul(ExpOfNonPositive(ei::pset1<Packet>(logit - normalizer.largest)),
                             ei::pset1<Packet>(normalizer.inverse_sum)));
  return logit == -std::numeric_limits<float>::infinity() && normalizer.largest > logit ? 0.0f
                                                                                        : lanes[0];
}

void FusedMultiplyAddPeakLoop(int64_t iterations, float* sink) {
  // 12 chains cover the FMA units' latency times their count (4 x 2 on current x86 cores) and
  // leave AVX2's 16 registers room for the two constants.
  Packet chains[kPeakLoopChains];
  for (int c = 0; c < kPeakLoopChains; ++c) {
    chains[c] = ei::pset1<Packet>(*sink + static_cast<float>(c));
  }
  const Packet scale = ei::pset1<Packet>(0.999f);
  const Packet offset = ei::pset1<Packet>(1e-3f);
  for (int64_t i = 0; i < iterations; ++i) {
    for (int c = 0; c < kPeakLoopChains; ++c) chains[c] = ei::pmadd(chains[c], scale, offset);
  }
  Packet sum = chains[0];
  for (int c = 1; c < kPeakLoopChains; ++c) sum = ei::padd(sum, chains[c]);
  *sink = ei::predux(sum);
}

int64_t PacketLanes() { return kLanes; }

const char* KernelInstructionSets() {
  // From the compiler's own macros: Eigen's list for its AVX build names neither AVX2 nor FMA,
  // which an AVX2 machine's kernels use.
  return ""
#ifdef __AVX512F__
         "AVX512, "
#endif
#ifdef __FMA__
         "FMA, "
#endif
#ifdef __AVX2__
         "AVX2, "
#endif
#ifdef __AVX__
         "AVX, "
#endif
#ifdef __SSE4_2__
         "SSE4.2, "
#endif
         "SSE2";
}

}  // namespace hscloc::dense_kernels
