// The CPU inference path of Network::Predict: the forward pass on the dense kernels, row block by
// row block. A block of FiLM features, its logits and its softmax stay in cache from modulation to
// label choice, where libtorch's operator-at-a-time path wrote and reread each [rows, C]
// intermediate.
#include <Eigen/Core>
#include <algorithm>
#include <atomic>
#include <functional>
#include <limits>
#include <memory>
#include <utility>
#include <vector>

#include "model/cpu_forward_blocks.h"
#include "model/dense_kernels.h"
#include "model/network_decoding.h"
#include "model/network_module.h"
#include "model/point_candidates.h"
#include "model/point_row_index.h"
#include "util/check.h"
#include "util/parallel.h"
#include "util/radix_sort.h"
#include "util/timer.h"

namespace hscloc {

namespace {

using cpu_forward::BlockScratch;
using cpu_forward::ForEachRowBlock;
using cpu_forward::kRowBlock;

// The forward pass of one Predict call, level by level: the descriptor-only layers once per
// keypoint, then the image- and label-dependent layers over every (image, keypoint) row, block
// by block, rows sorted so that those sharing an image and label prefix are adjacent.
class CpuForwardPass {
 public:
  CpuForwardPass(const Network& network, const DescriptorMatrix& descriptors,
                 const std::vector<uint32_t>& image_indices, const LabelTree& tree,
                 const Visibility* visibility_mask, DescriptorLayerCache& cache,
                 const PointRowIndex* index)
      : shape_(network.shape()),
        image_indices_(image_indices),
        tree_(tree),
        num_descriptors_(descriptors.rows()),
        num_rows_(descriptors.rows() * static_cast<int64_t>(image_indices.size())),
        channels_(network.options().channels),
        trunk_channels_(network.options().trunk_channels),
        embedding_dim_(network.options().embedding_dim),
        node_output_dim_(network.options().node_output_dim),
        shared_trunk_(network.options().shared_trunk),
        result_(AllocatePredictions(static_cast<int64_t>(image_indices.size()), descriptors.rows(),
                                    shape_.levels)),
        scaled_descriptors_(descriptors),
        parent_node_(num_rows_, 0),
        cache_(cache) {
    keyed_rows_.reserve(num_rows_);
    // L2-normalized rows, scaled by each level's input scale as the levels ask for it.
    for (int64_t i = 0; i < num_descriptors_; ++i) {
      scaled_descriptors_.row(i) /= std::max(scaled_descriptors_.row(i).norm(), 1e-12f);
    }
    if (visibility_mask != nullptr) {
      masks_ = std::make_unique<NodeVisibilityMasks>(image_indices, tree, *visibility_mask);
    }
    if (network.options().pooled_point_rows) {
      candidates_ = std::make_unique<PointCandidates>(tree, visibility_mask, image_indices,
                                                      &network.shape().point_row_offsets);
      point_rows_ = NetworkInternals::Module(network)->point_rows.data_ptr<float>();
      several_rows_per_point_ = !shape_.point_row_offsets.empty();
      if (several_rows_per_point_) pool_point_rows_ = dense_kernels::BestPointLogSumExpLogits;
      index_ = index;
    }
  }

  PointPredictions Run(const Network& network) {
    if (num_rows_ == 0) return std::move(result_);
    for (const Level& level : NetworkInternals::Module(network)->levels) {
      const Timer level_timer;
      const int depth = level->level();
      if (tree_.LevelHasChoice(depth)) {
        LevelWeights weights = level->CpuWeights(NetworkInternals::PackedWeights(network));
        weights.point_rows = point_rows_;
        descriptor_features_ = DescriptorFeatures(weights, depth, level->NumConditionedLayers());
        RunLevel(weights, depth, level->NumConditionedLayers());
      } else {
        SkipLevel(depth);
      }
      result_.level_milliseconds.push_back(level_timer.ElapsedMilliseconds());
      result_.level_flops.push_back(2.0 * static_cast<double>(multiply_adds_.exchange(0)));
    }
    ResolvePointIndices(tree_, result_);
    return std::move(result_);
  }

 private:
  uint8_t& LabelOf(int64_t row, int depth) {
    return result_.labels.data()[row * shape_.levels + depth];
  }

  // Every parent has a single child: label 0 with certainty, no network to run.
  void SkipLevel(int depth) {
    for (int64_t row = 0; row < num_rows_; ++row) {
      LabelOf(row, depth) = 0;
      parent_node_[row] = ChildNode(parent_node_[row], 0, tree_);
    }
  }

  // The level's descriptor-only layers, from the cache or computed into it.
  const float* DescriptorFeatures(const LevelWeights& weights, int depth, int layers) {
    if (weights.input_scale != current_scale_) {
      scaled_descriptors_ *= weights.input_scale / current_scale_;
      current_scale_ = weights.input_scale;
    }
    UninitializedVector<float>& features = cache_.levels[depth];
    if (features.empty()) {
      features.resize(num_descriptors_ * channels_);
      RunDescriptorLayers(weights, layers, features.data());
    }
    return features.data();
  }

  // Rows are decided a block at a time, except the run scored through the point row index: its
  // projections are gathered from every block and pooled all at once, so that each list of the
  // index streams from memory once for all the rows that probe it, not once per block.
  void RunLevel(const LevelWeights& weights, int depth, int layers) {
    SortDecidingRowsByConditioning(depth, weights.node_output_dim > 0,
                                   weights.point_rows != nullptr && masks_ != nullptr);
    FindIndexedRun(weights);
    ForEachRowBlock(static_cast<int64_t>(keyed_rows_.size()), [&](int64_t begin, int64_t end) {
      thread_local BlockScratch scratch;
      scratch.Reserve(end - begin, trunk_channels_, channels_, embedding_dim_, shape_.branching,
                      layers, node_output_dim_);
      GenerateModulation(weights, layers, begin, end, scratch);
      ModulateFeatures(weights, layers, begin, end, scratch);
      ComputeLogits(weights, depth, begin, end, scratch);
      float* logits = scratch.logits.data();
      ChooseLabels(depth, begin, std::min(end, indexed_begin_), logits);
      const int64_t after = std::max(begin, indexed_end_);
      ChooseLabels(depth, after, end, logits + (after - begin) * shape_.branching);
    });
    if (indexed_begin_ == indexed_end_) return;
    int64_t multiply_adds = 0;
    indexed_logits_ = index_->PooledLogits(indexed_projected_.data(), indexed_end_ - indexed_begin_,
                                           shape_.branching, &multiply_adds);
    multiply_adds_ += multiply_adds;
    ForEachRowBlock(indexed_end_ - indexed_begin_, [&](int64_t begin, int64_t end) {
      ChooseLabels(depth, indexed_begin_ + begin, indexed_begin_ + end,
                   indexed_logits_.data() + begin * shape_.branching);
    });
  }

  // The rows without an image at the root, which pool over every point of the map: one run of
  // keyed_rows_ (they share their key), [indexed_begin_, indexed_end_), scored through the index
  // where there is one; else an empty range past every row.
  void FindIndexedRun(const LevelWeights& weights) {
    const auto rows = static_cast<int64_t>(keyed_rows_.size());
    indexed_begin_ = indexed_end_ = rows;
    if (index_ == nullptr || weights.point_rows == nullptr) return;
    for (int64_t i = 0; i < rows; ++i) {
      if (!IndexedRow(keyed_rows_[i].second)) continue;
      indexed_begin_ = i;
      indexed_end_ = i + 1;
      while (indexed_end_ < rows && keyed_rows_[indexed_end_].first == keyed_rows_[i].first)
        ++indexed_end_;
      break;
    }
    indexed_projected_.resize((indexed_end_ - indexed_begin_) * node_output_dim_);
  }

  bool IndexedRow(int64_t row) const {
    return index_ != nullptr && parent_node_[row] == 0 &&
           image_indices_[row / num_descriptors_] == static_cast<uint32_t>(shape_.num_images);
  }

  // The trunk and the first conditioned layer's W h + b depend on the descriptor only.
  void RunDescriptorLayers(const LevelWeights& weights, int layers, float* features) {
    if (shared_trunk_) {
      RunFirstConditionedLayer(weights, SharedTrunk(weights, layers), features);
      return;
    }
    const int64_t descriptor_dim = shape_.descriptor_dim;
    multiply_adds_ += num_descriptors_ * (descriptor_dim * trunk_channels_ +
                                          trunk_channels_ * channels_ + channels_ * channels_);
    ForEachRowBlock(num_descriptors_, [&](int64_t begin, int64_t end) {
      thread_local BlockScratch scratch;
      scratch.Reserve(end - begin, trunk_channels_, channels_, embedding_dim_, shape_.branching,
                      layers, node_output_dim_);
      RunTrunk(weights, begin, end, scratch, scratch.linear.data());
      dense_kernels::Linear(scratch.linear.data(), end - begin, *weights.conditioned_weights[0],
                            weights.conditioned_biases[0], false, features + begin * channels_);
    });
  }

  // The trunk of descriptors [begin, end) into out [end - begin, C].
  void RunTrunk(const LevelWeights& weights, int64_t begin, int64_t end, BlockScratch& scratch,
                float* out) const {
    dense_kernels::Linear(scaled_descriptors_.data() + begin * shape_.descriptor_dim, end - begin,
                          *weights.trunk1_weight, weights.trunk1_bias, true, scratch.hidden.data());
    dense_kernels::Linear(scratch.hidden.data(), end - begin, *weights.trunk2_weight,
                          weights.trunk2_bias, true, out);
  }

  // A shared trunk's output [N, C], computed at the first level that asks for it.
  const float* SharedTrunk(const LevelWeights& weights, int layers) {
    if (cache_.shared_trunk_weight == weights.trunk1_weight.get())
      return cache_.shared_trunk.data();
    const int64_t descriptor_dim = shape_.descriptor_dim;
    multiply_adds_ +=
        num_descriptors_ * (descriptor_dim * trunk_channels_ + trunk_channels_ * channels_);
    cache_.shared_trunk.resize(num_descriptors_ * channels_);
    ForEachRowBlock(num_descriptors_, [&](int64_t begin, int64_t end) {
      thread_local BlockScratch scratch;
      scratch.Reserve(end - begin, trunk_channels_, channels_, embedding_dim_, shape_.branching,
                      layers, node_output_dim_);
      RunTrunk(weights, begin, end, scratch, cache_.shared_trunk.data() + begin * channels_);
    });
    cache_.shared_trunk_weight = weights.trunk1_weight.get();
    return cache_.shared_trunk.data();
  }

  void RunFirstConditionedLayer(const LevelWeights& weights, const float* trunk, float* features) {
    multiply_adds_ += num_descriptors_ * channels_ * channels_;
    ForEachRowBlock(num_descriptors_, [&](int64_t begin, int64_t end) {
      dense_kernels::Linear(trunk + begin * channels_, end - begin, *weights.conditioned_weights[0],
                            weights.conditioned_biases[0], false, features + begin * channels_);
    });
  }

  // Rows with the same image and label prefix share their modulation. Rows are visited in the
  // order of that key, so a block holds runs of equal keys and evaluates the generator once per
  // run, and a block's modulation never leaves the cache.
  //
  // A row whose parent has a single child has nothing to decide where the head gives missing
  // children no probability (node or point rows, `only_children_score`): its softmax is 1 on that
  // child, as for a level without choice (SkipLevel). It takes the child here and runs no layer.
  // At a city's finest level many parents hold one point (aachen: 40 % of that level's rows).
  // Pooled point rows under a visibility mask (`only_visible_children_score`) give no
  // probability to the children the row's image does not see either, so a parent of which the
  // image sees a single child decides nothing too.
  void SortDecidingRowsByConditioning(int depth, bool only_children_score,
                                      bool only_visible_children_score) {
    keyed_rows_.clear();
    for (int64_t row = 0; row < num_rows_; ++row) {
      const int64_t parent = parent_node_[row];
      const int64_t only_child = only_children_score && parent >= 0
                                     ? OnlyChildToScore(row, parent, only_visible_children_score)
                                     : -1;
      if (only_child >= 0) {
        LabelOf(row, depth) = static_cast<uint8_t>(only_child);
        parent_node_[row] = ChildNode(parent, only_child, tree_);
        continue;
      }
      int64_t key = image_indices_[row / num_descriptors_];
      for (int coarser = 0; coarser < depth; ++coarser) {
        key = key * shape_.branching + LabelOf(row, coarser);
      }
      keyed_rows_.emplace_back(key, row);
    }
    StableSortByKey(keyed_rows_, sort_scratch_);
  }

  // The one child of `parent` that can score for the row (with `visible_only`, among those its
  // image sees where it has a mask), or -1 when there are several.
  int64_t OnlyChildToScore(int64_t row, int64_t parent, bool visible_only) const {
    const int64_t children = tree_.NumChildren(static_cast<uint32_t>(parent));
    if (children == 1) return 0;
    const int slot =
        visible_only ? masks_->SlotOfK(static_cast<size_t>(row / num_descriptors_)) : -1;
    return slot < 0 ? -1
                    : masks_->OnlyKeptChild(slot, tree_.FirstChild(static_cast<uint32_t>(parent)),
                                            children);
  }

  bool StartsRun(int64_t sorted_index, int64_t begin) const {
    return sorted_index == begin ||
           keyed_rows_[sorted_index].first != keyed_rows_[sorted_index - 1].first;
  }

  // FiLM parameters once per run of equal keys in sorted rows [begin, end).
  void GenerateModulation(const LevelWeights& weights, int layers, int64_t begin, int64_t end,
                          BlockScratch& scratch) {
    const int64_t e = embedding_dim_;
    int64_t runs = 0;
    for (int64_t i = begin; i < end; ++i) {
      const int64_t row = keyed_rows_[i].second;
      if (StartsRun(i, begin)) {
        // The generator input of the run: image embedding plus the parent's (or the coarser
        // labels') embeddings.
        auto sum = Eigen::Map<Eigen::VectorXf>(scratch.embedding.data() + runs * e, e);
        sum = Eigen::Map<const Eigen::VectorXf>(
            weights.image_embedding + image_indices_[row / num_descriptors_] * e, e);
        if (weights.node_embedding != nullptr) {
          const int64_t node_row =
              std::max<int64_t>(parent_node_[row] - weights.node_embedding_first, 0);
          sum += Eigen::Map<const Eigen::VectorXf>(weights.node_embedding + node_row * e, e);
        }
        for (int coarser = 0; coarser < static_cast<int>(weights.label_embeddings.size());
             ++coarser) {
          sum += Eigen::Map<const Eigen::VectorXf>(
              weights.label_embeddings[coarser] + LabelOf(row, coarser) * e, e);
        }
        ++runs;
      }
      scratch.run_of_row[i - begin] = static_cast<int32_t>(runs - 1);
      scratch.descriptor_of_row[i - begin] = row % num_descriptors_;
    }
    multiply_adds_ += runs * (e * e + layers * 2 * e * channels_);
    dense_kernels::EluInPlace(scratch.embedding.data(), runs * e);
    dense_kernels::Linear(scratch.embedding.data(), runs, *weights.generator_weight,
                          weights.generator_bias, true, scratch.generator.data());
    for (int layer = 0; layer < layers; ++layer) {
      dense_kernels::Linear(scratch.generator.data(), runs, *weights.gamma_weights[layer],
                            weights.gamma_biases[layer], false, scratch.gammas[layer].data());
      dense_kernels::Linear(scratch.generator.data(), runs, *weights.beta_weights[layer],
                            weights.beta_biases[layer], false, scratch.betas[layer].data());
    }
  }

  // h_i = ELU(gamma_i * (W_i h_{i-1} + b_i) + beta_i) for every conditioned layer.
  void ModulateFeatures(const LevelWeights& weights, int layers, int64_t begin, int64_t end,
                        BlockScratch& scratch) {
    const int64_t block_rows = end - begin;
    multiply_adds_ += block_rows * (layers - 1) * channels_ * channels_;
    dense_kernels::ModulateElu(descriptor_features_, scratch.descriptor_of_row.data(),
                               scratch.gammas[0].data(), scratch.betas[0].data(),
                               scratch.run_of_row.data(), block_rows, channels_,
                               scratch.features.data());
    for (int layer = 1; layer < layers; ++layer) {
      dense_kernels::Linear(scratch.features.data(), block_rows,
                            *weights.conditioned_weights[layer], weights.conditioned_biases[layer],
                            false, scratch.linear.data());
      dense_kernels::ModulateElu(scratch.linear.data(), nullptr, scratch.gammas[layer].data(),
                                 scratch.betas[layer].data(), scratch.run_of_row.data(), block_rows,
                                 channels_, scratch.features.data());
    }
  }

  // Logits over the children, from the level's shared output layer, the parent's node rows or
  // the pooled point rows.
  void ComputeLogits(const LevelWeights& weights, int depth, int64_t begin, int64_t end,
                     BlockScratch& scratch) {
    const int64_t branching = shape_.branching;
    const int64_t block_rows = end - begin;
    if (weights.node_output_dim == 0) {
      multiply_adds_ += block_rows * channels_ * branching;
      dense_kernels::Linear(scratch.features.data(), block_rows, *weights.output_weight,
                            weights.output_bias, false, scratch.logits.data());
      return;
    }
    // Each run shares its parent: its children's rows are contiguous in the node table.
    const int64_t row_width = node_output_dim_ + 1;
    multiply_adds_ += block_rows * channels_ * node_output_dim_;
    dense_kernels::Linear(scratch.features.data(), block_rows, *weights.projection_weight,
                          weights.projection_bias, false, scratch.projected.data());
    if (weights.shortcut_scale != nullptr) AddDescriptorShortcut(weights, end - begin, scratch);
    if (weights.point_rows != nullptr) {
      PooledLogits(weights.point_rows, depth, begin, end, scratch);
      return;
    }
    for (int64_t i = begin; i < end;) {
      int64_t run_end = i + 1;
      while (run_end < end && keyed_rows_[run_end].first == keyed_rows_[i].first) ++run_end;
      const int64_t parent = parent_node_[keyed_rows_[i].second];
      const int64_t count = parent < 0 ? 0 : tree_.NumChildren(static_cast<uint32_t>(parent));
      const int64_t first =
          parent < 0 ? 0
                     : tree_.FirstChild(static_cast<uint32_t>(parent)) - weights.node_rows_first;
      float* logits = scratch.logits.data() + (i - begin) * branching;
      multiply_adds_ += (run_end - i) * count * node_output_dim_;
      dense_kernels::NodeLogits(scratch.projected.data() + (i - begin) * node_output_dim_,
                                run_end - i, node_output_dim_,
                                weights.node_rows + first * row_width, count, branching, logits);
      if (count == 0) std::fill_n(logits, (run_end - i) * branching, 0.0f);
      i = run_end;
    }
  }

  // projected += s x for the descriptor shortcut, x the row's unit descriptor (the levels' input
  // scale undone).
  void AddDescriptorShortcut(const LevelWeights& weights, int64_t block_rows,
                             BlockScratch& scratch) const {
    const int64_t dim = shape_.descriptor_dim;
    const float factor = *weights.shortcut_scale / current_scale_;
    for (int64_t i = 0; i < block_rows; ++i) {
      const float* descriptor = scaled_descriptors_.data() + scratch.descriptor_of_row[i] * dim;
      float* projected = scratch.projected.data() + i * dim;
      for (int64_t d = 0; d < dim; ++d) projected[d] += factor * descriptor[d];
    }
  }

  // Each run of rows shares its image and parent, hence its candidate points: their rows are
  // gathered a chunk at a time, and each child keeps the score of its best point, a point's
  // score being its row's or, with several rows per point, their log-sum-exp (PooledPointLogits,
  // Pooling::kBestPoint). They are scored and pooled in one pass (dense_kernels::PooledMaxLogits,
  // BestPointLogSumExpLogits): a score matrix written, biased and reread took most of an id-free
  // pass at aachen scale.
  void PooledLogits(const float* point_rows, int depth, int64_t begin, int64_t end,
                    BlockScratch& scratch) {
    const int64_t branching = shape_.branching;
    const int64_t row_width = node_output_dim_ + 1;
    std::fill_n(scratch.logits.data(), (end - begin) * branching,
                -std::numeric_limits<float>::infinity());
    for (int64_t i = begin; i < end;) {
      int64_t run_end = i + 1;
      while (run_end < end && keyed_rows_[run_end].first == keyed_rows_[i].first) ++run_end;
      const int64_t row = keyed_rows_[i].second;
      const int64_t parent = parent_node_[row];
      if (i >= indexed_begin_ && i < indexed_end_) {
        // Pooled after every block (RunLevel); its projections wait in indexed_projected_.
        std::copy_n(scratch.projected.data() + (i - begin) * node_output_dim_,
                    (run_end - i) * node_output_dim_,
                    indexed_projected_.data() + (i - indexed_begin_) * node_output_dim_);
        i = run_end;
        continue;
      }
      const CandidateSpan span =
          parent < 0 ? CandidateSpan{}
                     : candidates_->Under(candidates_->SlotOf(row / num_descriptors_),
                                          static_cast<uint32_t>(parent));
      const int64_t run_rows = run_end - i;
      float* run_logits = scratch.logits.data() + (i - begin) * branching;
      for (size_t first = 0; first < span.size;) {
        const size_t count = ChunkEnd(span, first) - first;
        // A whole range of ranks (every point under the parent) is already contiguous in the
        // table; only an image's list of ranks needs gathering.
        const float* rows = span.rows == nullptr
                                ? point_rows + (span.first + first) * row_width
                                : GatherRows(point_rows, span, first, count, scratch);
        FindSegments(span, first, count, depth, scratch);
        multiply_adds_ += run_rows * static_cast<int64_t>(count) * node_output_dim_;
        pool_point_rows_(
            scratch.projected.data() + (i - begin) * node_output_dim_, run_rows, node_output_dim_,
            rows, scratch.segment_starts.data(), scratch.segment_groups.data(),
            static_cast<int64_t>(scratch.segment_groups.size()), branching, run_logits);
        first += count;
      }
      // A row without candidates (its path left the tree) keeps finite logits.
      if (span.size == 0) std::fill_n(run_logits, run_rows * branching, 0.0f);
      i = run_end;
    }
  }

  // The end of the chunk of the span's candidates from `first`: about kChunk rows, and with
  // several rows per point never inside a point, whose rows are pooled together.
  size_t ChunkEnd(const CandidateSpan& span, size_t first) const {
    constexpr size_t kChunk = 512;
    size_t end = std::min(span.size, first + kChunk);
    if (!several_rows_per_point_) return end;
    // A span holds each of its points' rows side by side.
    const uint32_t end_of_point =
        candidates_->FirstRowOfRank(candidates_->RankOfRow(span[end - 1]) + 1);
    while (end < span.size && span[end] < end_of_point) ++end;
    return end;
  }

  // The rows of candidates [first, first + count) of the span, copied side by side.
  const float* GatherRows(const float* point_rows, const CandidateSpan& span, size_t first,
                          size_t count, BlockScratch& scratch) const {
    const int64_t row_width = node_output_dim_ + 1;
    scratch.gathered.resize(count * row_width);
    for (size_t m = 0; m < count; ++m) {
      std::copy_n(point_rows + span[first + m] * row_width, row_width,
                  scratch.gathered.data() + m * row_width);
    }
    return scratch.gathered.data();
  }

  // Candidates come in rank order, so a child's points are one run of the chunk: where each
  // segment starts (the last entry: the chunk's end) and its child. A segment is a child's run,
  // or with several rows per point one point's rows.
  void FindSegments(const CandidateSpan& span, size_t first, size_t count, int depth,
                    BlockScratch& scratch) const {
    scratch.segment_starts.clear();
    scratch.segment_groups.clear();
    uint32_t end_of_point = 0;
    for (size_t m = 0; m < count; ++m) {
      const uint32_t row = span[first + m];
      if (m > 0 && row < end_of_point) continue;  // the point of the row before
      const uint32_t rank = candidates_->RankOfRow(row);
      end_of_point = candidates_->FirstRowOfRank(rank + 1);
      const uint8_t group = candidates_->LabelOfRow(row, depth);
      if (several_rows_per_point_ || m == 0 || group != scratch.segment_groups.back()) {
        scratch.segment_starts.push_back(static_cast<uint32_t>(m));
        scratch.segment_groups.push_back(group);
      }
    }
    scratch.segment_starts.push_back(static_cast<uint32_t>(count));
  }

  // Rows [begin, end) of keyed_rows_ (none where end <= begin), their logits from `logits` on.
  void ChooseLabels(int depth, int64_t begin, int64_t end, float* logits) {
    if (end <= begin) return;
    const int64_t branching = shape_.branching;
    thread_local std::vector<dense_kernels::SoftmaxNormalizer> normalizers;
    normalizers.resize(end - begin);
    dense_kernels::SoftmaxNormalizers(logits, end - begin, branching, normalizers.data());
    for (int64_t i = begin; i < end; ++i) {
      const int64_t row = keyed_rows_[i].second;
      const float* row_logits = logits + (i - begin) * branching;
      const int slot = masks_ ? masks_->SlotOfK(static_cast<size_t>(row / num_descriptors_)) : -1;
      const int64_t parent = parent_node_[row];
      const int64_t best = ChooseLabel(row_logits, branching, masks_.get(), slot, parent, tree_);
      LabelOf(row, depth) = static_cast<uint8_t>(best);
      result_.confidences.data()[row] *=
          dense_kernels::SoftmaxOf(row_logits[best], normalizers[i - begin]);
      parent_node_[row] = ChildNode(parent, best, tree_);
    }
  }

  const NetworkShape& shape_;
  const std::vector<uint32_t>& image_indices_;
  const LabelTree& tree_;
  const int64_t num_descriptors_;
  const int64_t num_rows_;  // images x descriptors, row k * N + n
  const int64_t channels_;
  const int64_t trunk_channels_;
  const int64_t embedding_dim_;
  const int64_t node_output_dim_;
  const bool shared_trunk_;
  PointPredictions result_;
  DescriptorMatrix scaled_descriptors_;
  float current_scale_ = 1;
  std::unique_ptr<NodeVisibilityMasks> masks_;
  // Pooled point rows: the candidates of the call's images, and the network's table.
  std::unique_ptr<PointCandidates> candidates_;
  const float* point_rows_ = nullptr;
  bool several_rows_per_point_ = false;
  decltype(&dense_kernels::PooledMaxLogits) pool_point_rows_ = dense_kernels::PooledMaxLogits;
  // Where given, rows without an image score the root's children through it: the level's such
  // rows, their projections [rows, node_output_dim] and their logits [rows, branching].
  const PointRowIndex* index_ = nullptr;
  int64_t indexed_begin_ = 0;
  int64_t indexed_end_ = 0;
  std::vector<float> indexed_projected_;
  std::vector<float> indexed_logits_;
  // The tree node of every row's label prefix (-1 once a path leaves the tree).
  std::vector<int64_t> parent_node_;
  // Every level's first conditioned layer's W h + b of every descriptor, [N, C], and the current
  // level's.
  DescriptorLayerCache& cache_;
  const float* descriptor_features_ = nullptr;
  // (image and label prefix, row), sorted; rows come in increasing order, so the stable sort by
  // key is the pairs' order.
  std::vector<std::pair<int64_t, int64_t>> keyed_rows_;
  std::vector<std::pair<int64_t, int64_t>> sort_scratch_;
  // The level's multiply-adds so far, from every compute thread.
  std::atomic<int64_t> multiply_adds_{0};
};

}  // namespace

PointPredictions PredictOnCpu(const Network& network, const DescriptorMatrix& descriptors,
                              const std::vector<uint32_t>& image_indices, const LabelTree& tree,
                              const Visibility* visibility_mask, DescriptorLayerCache* cache,
                              const PointRowIndex* index) {
  DescriptorLayerCache own;
  if (cache == nullptr) {
    cache = &own;
  } else if (cache->descriptors != nullptr &&
             (cache->descriptors != descriptors.data() || cache->rows != descriptors.rows() ||
              cache->cols != descriptors.cols())) {
    ThrowInvalidArgument("Predict: the descriptor layer cache was filled from other descriptors");
  }
  cache->descriptors = descriptors.data();
  cache->rows = descriptors.rows();
  cache->cols = descriptors.cols();
  cache->levels.resize(network.shape().levels);
  if (index != nullptr && index->NumPoints() != network.shape().NumPointRows()) {
    ThrowInvalidArgument("Predict: a point row index of {} rows for a network of {}",
                         index->NumPoints(), network.shape().NumPointRows());
  }
  return CpuForwardPass(network, descriptors, image_indices, tree, visibility_mask, *cache, index)
      .Run(network);
}

}  // namespace hscloc
