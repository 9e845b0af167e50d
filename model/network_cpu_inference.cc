// The CPU inference path of Network::Predict: the forward pass on the dense kernels, row block by
// row block. A block of FiLM features, its logits and its softmax stay in cache from modulation to
// label choice, where libtorch's operator-at-a-time path wrote and reread each [rows, C]
// intermediate.
#include <Eigen/Core>
#include <algorithm>
#include <functional>
#include <memory>
#include <utility>
#include <vector>

#include "model/dense_kernels.h"
#include "model/network_decoding.h"
#include "model/network_module.h"
#include "util/parallel.h"
#include "util/timer.h"

namespace hscloc {

namespace {

constexpr int64_t kRowBlock = 128;

// body(begin, end) over blocks of kRowBlock rows, on the compute threads.
void ForEachRowBlock(int64_t rows, const std::function<void(int64_t begin, int64_t end)>& body) {
  const int64_t blocks = (rows + kRowBlock - 1) / kRowBlock;
  ParallelFor(static_cast<size_t>(blocks), ComputeThreads(), [&](size_t first, size_t last) {
    for (size_t block = first; block < last; ++block) {
      const int64_t begin = static_cast<int64_t>(block) * kRowBlock;
      body(begin, std::min(rows, begin + kRowBlock));
    }
  });
}

// Per-thread buffers of one row block, kept between blocks and calls: fresh allocations of this
// size would each be zeroed and page-faulted in.
struct BlockScratch {
  std::vector<float> hidden, embedding, generator, features, linear, logits, projected;
  std::vector<std::vector<float>> gammas, betas;
  std::vector<int32_t> run_of_row;
  std::vector<int64_t> descriptor_of_row;

  void Reserve(int64_t rows, int64_t trunk_channels, int64_t channels, int64_t embedding_dim,
               int64_t branching, int layers, int64_t projected_dim) {
    const auto grow = [](auto& buffer, int64_t size) {
      if (static_cast<int64_t>(buffer.size()) < size) buffer.resize(size);
    };
    grow(hidden, rows * trunk_channels);
    grow(embedding, rows * embedding_dim);
    grow(generator, rows * embedding_dim);
    grow(features, rows * channels);
    grow(linear, rows * channels);
    grow(logits, rows * branching);
    grow(projected, rows * projected_dim);
    grow(run_of_row, rows);
    grow(descriptor_of_row, rows);
    if (static_cast<int>(gammas.size()) < layers) {
      gammas.resize(layers);
      betas.resize(layers);
    }
    for (int layer = 0; layer < layers; ++layer) {
      grow(gammas[layer], rows * channels);
      grow(betas[layer], rows * channels);
    }
  }
};

}  // namespace

PointPredictions PredictOnCpu(const Network& network, const DescriptorMatrix& descriptors,
                              const std::vector<uint32_t>& image_indices, const LabelTree& tree,
                              const Visibility* visibility_mask) {
  namespace dk = dense_kernels;
  const NetworkShape& s = network.shape();
  const int64_t n = descriptors.rows();
  const int64_t k = static_cast<int64_t>(image_indices.size());
  const int64_t rows = n * k;
  const int64_t d = s.descriptor_dim;
  const int64_t c = network.options().channels;
  const int64_t h = network.options().trunk_channels;
  const int64_t e = network.options().embedding_dim;
  const int64_t branching = s.branching;
  const int64_t r_dim = network.options().node_output_dim;
  PointPredictions result = AllocatePredictions(k, n, s.levels);
  if (rows == 0) return result;

  // L2-normalized rows times the trunk's input scale; every level's scale is sqrt(D), so the rows
  // are scaled once and again only if a level were to differ.
  DescriptorMatrix scaled = descriptors;
  for (int64_t i = 0; i < n; ++i) scaled.row(i) /= std::max(scaled.row(i).norm(), 1e-12f);
  float current_scale = 1;
  std::unique_ptr<NodeVisibilityMasks> masks;
  if (visibility_mask != nullptr) {
    masks = std::make_unique<NodeVisibilityMasks>(image_indices, tree, *visibility_mask);
  }
  // The tree node of every row's label prefix (-1 once a path leaves the tree).
  std::vector<int64_t> parent_node(rows, 0);

  uint8_t* labels = result.labels.data();
  float* confidences = result.confidences.data();
  std::vector<float> shared(n * c);
  std::vector<std::pair<int64_t, int64_t>> keyed_rows(rows);  // (image and label prefix, row)
  for (const Level& level : NetworkInternals::Module(network)->levels) {
    const Timer level_timer;
    const int depth = level->level();
    if (!tree.LevelHasChoice(depth)) {
      // Every parent has a single child: label 0 with certainty, no network to run.
      for (int64_t r = 0; r < rows; ++r) {
        labels[r * s.levels + depth] = 0;
        parent_node[r] = ChildNode(parent_node[r], 0, tree);
      }
      result.level_milliseconds.push_back(level_timer.ElapsedMilliseconds());
      continue;
    }
    const LevelWeights w = level->CpuWeights();
    const int layers = level->NumConditionedLayers();

    // Descriptor-only part, once per keypoint: trunk and the first conditioned layer's W h + b.
    if (w.input_scale != current_scale) {
      scaled *= w.input_scale / current_scale;
      current_scale = w.input_scale;
    }
    ForEachRowBlock(n, [&](int64_t begin, int64_t end) {
      const int64_t m = end - begin;
      thread_local BlockScratch scratch;
      scratch.Reserve(m, h, c, e, branching, layers, r_dim);
      dk::Linear(scaled.data() + begin * d, m, d, w.trunk1_weight, w.trunk1_bias, h, true,
                 scratch.hidden.data());
      dk::Linear(scratch.hidden.data(), m, h, w.trunk2_weight, w.trunk2_bias, c, true,
                 scratch.linear.data());
      dk::Linear(scratch.linear.data(), m, c, w.conditioned_weights[0], w.conditioned_biases[0], c,
                 false, shared.data() + begin * c);
    });

    // Rows with the same image and label prefix share their modulation. Rows are visited in the
    // order of that key, so a block holds runs of equal keys and evaluates the generator once per
    // run, and a block's modulation never leaves the cache.
    for (int64_t r = 0; r < rows; ++r) {
      int64_t key = image_indices[r / n];
      for (int column = 0; column < depth; ++column) {
        key = key * branching + labels[r * s.levels + column];
      }
      keyed_rows[r] = {key, r};
    }
    std::sort(keyed_rows.begin(), keyed_rows.end());

    ForEachRowBlock(rows, [&](int64_t begin, int64_t end) {
      const int64_t m = end - begin;
      thread_local BlockScratch scratch;
      scratch.Reserve(m, h, c, e, branching, layers, r_dim);
      int64_t runs = 0;
      for (int64_t i = begin; i < end; ++i) {
        if (i == begin || keyed_rows[i].first != keyed_rows[i - 1].first) {
          // The generator input of the run: image embedding plus the coarser labels' embeddings.
          const int64_t r = keyed_rows[i].second;
          auto sum = Eigen::Map<Eigen::VectorXf>(scratch.embedding.data() + runs * e, e);
          sum = Eigen::Map<const Eigen::VectorXf>(w.image_embedding + image_indices[r / n] * e, e);
          if (w.node_embedding != nullptr) {
            const int64_t row = std::max<int64_t>(parent_node[r] - w.node_embedding_first, 0);
            sum += Eigen::Map<const Eigen::VectorXf>(w.node_embedding + row * e, e);
          }
          for (int column = 0; column < static_cast<int>(w.label_embeddings.size()); ++column) {
            sum += Eigen::Map<const Eigen::VectorXf>(
                w.label_embeddings[column] + labels[r * s.levels + column] * e, e);
          }
          ++runs;
        }
        scratch.run_of_row[i - begin] = static_cast<int32_t>(runs - 1);
        scratch.descriptor_of_row[i - begin] = keyed_rows[i].second % n;
      }
      dk::EluInPlace(scratch.embedding.data(), runs * e);
      dk::Linear(scratch.embedding.data(), runs, e, w.generator_weight, w.generator_bias, e, true,
                 scratch.generator.data());
      for (int layer = 0; layer < layers; ++layer) {
        dk::Linear(scratch.generator.data(), runs, e, w.gamma_weights[layer], w.gamma_biases[layer],
                   c, false, scratch.gammas[layer].data());
        dk::Linear(scratch.generator.data(), runs, e, w.beta_weights[layer], w.beta_biases[layer],
                   c, false, scratch.betas[layer].data());
      }

      dk::ModulateElu(shared.data(), scratch.descriptor_of_row.data(), scratch.gammas[0].data(),
                      scratch.betas[0].data(), scratch.run_of_row.data(), m, c,
                      scratch.features.data());
      for (int layer = 1; layer < layers; ++layer) {
        dk::Linear(scratch.features.data(), m, c, w.conditioned_weights[layer],
                   w.conditioned_biases[layer], c, false, scratch.linear.data());
        dk::ModulateElu(scratch.linear.data(), nullptr, scratch.gammas[layer].data(),
                        scratch.betas[layer].data(), scratch.run_of_row.data(), m, c,
                        scratch.features.data());
      }
      if (w.node_output_dim > 0) {
        // Each run shares its parent: its children's rows are contiguous in the node table.
        dk::Linear(scratch.features.data(), m, c, w.projection_weight, w.projection_bias, r_dim,
                   false, scratch.projected.data());
        for (int64_t i = begin; i < end;) {
          int64_t run_end = i + 1;
          while (run_end < end && keyed_rows[run_end].first == keyed_rows[i].first) ++run_end;
          const int64_t parent = parent_node[keyed_rows[i].second];
          const int64_t count = parent < 0 ? 0 : tree.NumChildren(static_cast<uint32_t>(parent));
          const int64_t first =
              parent < 0 ? 0 : tree.FirstChild(static_cast<uint32_t>(parent)) - w.node_rows_first;
          dk::NodeLogits(scratch.projected.data() + (i - begin) * r_dim, run_end - i, r_dim,
                         w.node_rows + first * (r_dim + 1), count, branching,
                         scratch.logits.data() + (i - begin) * branching);
          if (count == 0) {
            std::fill_n(scratch.logits.data() + (i - begin) * branching, (run_end - i) * branching,
                        0.0f);
          }
          i = run_end;
        }
      } else {
        dk::Linear(scratch.features.data(), m, c, w.output_weight, w.output_bias, branching,
                   false, scratch.logits.data());
      }
      dk::SoftmaxRowsInPlace(scratch.logits.data(), m, branching);
      for (int64_t i = begin; i < end; ++i) {
        const int64_t r = keyed_rows[i].second;
        const float* probabilities = scratch.logits.data() + (i - begin) * branching;
        const int slot = masks ? masks->SlotOfK(static_cast<size_t>(r / n)) : -1;
        const int64_t parent = parent_node[r];
        const int64_t best = ChooseLabel(probabilities, branching, masks.get(), slot, parent, tree);
        labels[r * s.levels + depth] = static_cast<uint8_t>(best);
        confidences[r] *= probabilities[best];
        parent_node[r] = ChildNode(parent, best, tree);
      }
    });
    result.level_milliseconds.push_back(level_timer.ElapsedMilliseconds());
  }
  ResolvePointIndices(tree, result);
  return result;
}

}  // namespace hscloc
