// The dense fp32 kernels of the network's CPU inference: matrix products, the FiLM modulation with
// its ELU, and row softmax, on raw row-major arrays. The matrix product also computes the
// similarities of nearest-neighbour matching (localization/nearest_neighbor_matcher.h).
//
// They are compiled for the build machine's instruction set (CMake HSCLOC_KERNEL_ARCH, "native" by
// default: AVX-512 where the CPU has it), while the rest of hscloc keeps the distribution's
// baseline, which libraries such as Ceres share. Their Eigen lives in a namespace of its own, so
// no Eigen symbol compiled for the wider instruction set can stand in for one compiled without it.
// That is why this header exposes pointers only, and why the kernels are single-threaded: callers
// split rows across threads.
#pragma once

#include <cstdint>
#include <vector>

namespace hscloc::dense_kernels {

// A Linear weight [out_features x in_features] (as torch.nn.Linear stores it) laid out for the
// matrix-product kernel: panels of
// PanelWidth() output features, each stored input feature by input feature, the last panel padded
// with zeros. The kernel then reads the weights in the order it multiplies them; a layer run over
// many row blocks is packed once (model/packed_weight_cache.h), not once per block.
struct PackedMatrix {
  int64_t out_features = 0;
  int64_t in_features = 0;
  std::vector<float> panels;
};
int64_t PanelWidth();
PackedMatrix PackMatrix(const float* weight, int64_t out_features, int64_t in_features);

// out[rows x out_features] = in[rows x in_features] * weight^T + bias[out_features], then ELU
// where `elu`; `out` must not alias `in`. Each output is one chain of fused multiply-adds over the
// input features in order, then the bias: the same bits wherever its row sits in `in`, and for
// any vector width.
void Linear(const float* in, int64_t rows, const PackedMatrix& weight, const float* bias, bool elu,
            float* out);

// out[r, :] = ELU(gamma[modulation_rows[r], :] * source[source_rows[r], :] +
//                 beta[modulation_rows[r], :]) for r < rows, all rows of `columns` floats;
// source_rows == nullptr means row r of `source`.
void ModulateElu(const float* source, const int64_t* source_rows, const float* gamma,
                 const float* beta, const int32_t* modulation_rows, int64_t rows, int64_t columns,
                 float* out);

void EluInPlace(float* values, int64_t count);

// Logits of one parent's children from per-node output rows: for i < num_inputs and
// c < num_children, out[i * out_columns + c] = <projected[i, :dim], node_rows[c, :dim]> +
// node_rows[c, dim] (node rows of dim + 1 floats: weights, then the bias); columns
// num_children .. out_columns - 1 are set to -infinity (no such child).
void NodeLogits(const float* projected, int64_t num_inputs, int64_t dim, const float* node_rows,
                int64_t num_children, int64_t out_columns, float* out);

// Pooled logits of one run of inputs against a chunk of candidate point rows (rows of dim + 1
// floats: weights, then the bias), whose points come in segments of one child each: points
// [segment_starts[k], segment_starts[k + 1]) belong to child segment_groups[k]. For i <
// num_inputs, out[i * out_columns + segment_groups[k]] becomes the larger of its value and the best
// score <projected[i, :dim], w_p> + b_p over segment k's points. The scores are never stored, and
// each one is summed in the same order (the bias, then the dimensions in order) wherever its input
// sits in memory.
void PooledMaxLogits(const float* projected, int64_t num_inputs, int64_t dim,
                     const float* point_rows, const uint32_t* segment_starts,
                     const uint8_t* segment_groups, int64_t num_segments, int64_t out_columns,
                     float* out);

// PooledMaxLogits for segments that are each one point's rows: a point scores the log-sum-exp
// of its rows' scores, and out[i * out_columns + segment_groups[k]] becomes the larger of its value
// and point k's score (each child keeps its best point). A point's rows must be one segment.
void BestPointLogSumExpLogits(const float* projected, int64_t num_inputs, int64_t dim,
                              const float* point_rows, const uint32_t* segment_starts,
                              const uint8_t* segment_groups, int64_t num_segments,
                              int64_t out_columns, float* out);

// One more candidate for each of `count` queries, given its similarity to each (values) and its
// index: where the value is above best[q], the old best becomes second[q] and the candidate
// best_index[q]; elsewhere second[q] keeps the larger of the two. Candidates scanned so in order
// leave each query its best and second-best similarity and the first candidate with the best.
void UpdateBestTwo(const float* values, int64_t count, int32_t index, float* best, float* second,
                   int32_t* best_index);
// The index of the first largest of values[0, count), count > 0.
int64_t FirstArgMax(const float* values, int64_t count);

// The softmax of rows of logits, never written out: the label choice needs one child's
// probability per row, and the logits' order is the probabilities' order. Per row, its largest
// logit and the inverse of its sum of exp(logit - largest); a row's trailing -inf values (children
// a parent does not have) take no exp, the rest is summed in one fixed order wherever the row
// sits. A row of -inf alone gets a NaN sum, as its softmax is NaN.
struct SoftmaxNormalizer {
  float largest = 0;
  float inverse_sum = 0;
};
void SoftmaxNormalizers(const float* logits, int64_t rows, int64_t columns,
                        SoftmaxNormalizer* normalizers);
// The softmax probability of one logit of a row with that normalizer; a -inf logit gets 0.
float SoftmaxOf(float logit, const SoftmaxNormalizer& normalizer);

// kPeakLoopChains independent chains of `iterations` fused multiply-add packets each, on registers
// only (`sink` keeps them from being optimized away): 2 x PacketLanes() x kPeakLoopChains x
// iterations FLOPs over the time this takes is the core's arithmetic peak, which no kernel passes.
constexpr int kPeakLoopChains = 12;
void FusedMultiplyAddPeakLoop(int64_t iterations, float* sink);
int64_t PacketLanes();

// The SIMD instruction sets the kernels were compiled for, e.g. "AVX512, FMA, AVX2, ...".
const char* KernelInstructionSets();

}  // namespace hscloc::dense_kernels
