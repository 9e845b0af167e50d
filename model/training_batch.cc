#include "model/training_batch.h"

#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>

#include "model/network_decoding.h"
#include "model/network_module.h"
#include "util/random.h"

namespace hscloc {
namespace {

// Random stream keys (util/random.h); model/trainer.cc holds the held-out split's.
constexpr uint64_t kStreamShuffle = 0x73687566;   // "shuf"
constexpr uint64_t kStreamAugment = 0x6175676d;   // "augm"
constexpr uint64_t kStreamSiblings = 0x7369626c;  // "sibl"

// The per-row part of a batch, on the CPU.
struct BatchRows {
  torch::Tensor descriptors;       // [B, D], augmented, not yet normalized
  torch::Tensor images;            // [B]
  torch::Tensor labels;            // [B, levels]
  std::vector<int> source_images;  // the observations' images, before image dropout
  std::vector<uint32_t> points;    // the observed points
};

BatchRows DrawRows(const BatchContext& context, SampleOrder& order, int64_t iteration) {
  const Scene& scene = context.scene;
  const LabelTree& tree = context.tree;
  const TrainerOptions& options = context.options;
  const int64_t size = options.batch_size;
  const int64_t dim = scene.Dimension();
  const int levels = tree.levels();
  std::vector<uint32_t> observations(size);
  for (int64_t row = 0; row < size; ++row) {
    observations[row] = order.At(static_cast<uint64_t>(iteration * size + row));
  }
  BatchRows rows{torch::empty({size, dim}, torch::kFloat32), torch::empty({size}, torch::kInt64),
                 torch::empty({size, levels}, torch::kInt64), std::vector<int>(size),
                 std::vector<uint32_t>(size)};
  float* descriptor_data = rows.descriptors.data_ptr<float>();
  int64_t* image_data = rows.images.data_ptr<int64_t>();
  int64_t* label_data = rows.labels.data_ptr<int64_t>();
  const DescriptorAugmentationOptions& augmentation = options.augmentation;
  const double noise_sigma = augmentation.noise_norm / std::sqrt(static_cast<double>(dim));
  const uint32_t no_image = static_cast<uint32_t>(scene.NumImages());
  at::parallel_for(0, size, 64, [&](int64_t begin, int64_t end) {
    for (int64_t row = begin; row < end; ++row) {
      const uint32_t observation = observations[row];
      Random random(options.seed,
                    {kStreamAugment, static_cast<uint64_t>(iteration), static_cast<uint64_t>(row)});
      Eigen::Map<Eigen::VectorXf> x(descriptor_data + row * dim, dim);
      x = scene.observation_descriptors.row(observation).transpose();
      if (augmentation.enabled) {
        x /= std::max(x.norm(), 1e-12f);
        for (int64_t i = 0; i < dim; ++i) {
          x[i] = random.Bernoulli(augmentation.dimension_dropout)
                     ? 0.0f
                     : x[i] + static_cast<float>(random.Normal(0, noise_sigma));
        }
      }
      const bool drop_image = options.image_dropout > 0 && random.Bernoulli(options.image_dropout);
      rows.source_images[row] = static_cast<int>(scene.observation_image_indices[observation]);
      rows.points[row] = scene.observation_point_indices[observation];
      image_data[row] = drop_image ? no_image : scene.observation_image_indices[observation];
      const LabelTree::Label* path =
          tree.LabelsOfPoint(scene.observation_point_indices[observation]);
      std::copy(path, path + levels, label_data + row * levels);
    }
  });
  return rows;
}

// The batch's rows at one level, on the CPU: each row's image, label and parent node.
struct LevelRows {
  int64_t size = 0;
  const int64_t* images = nullptr;  // [size]
  const int64_t* labels = nullptr;  // [size, levels]
  const int64_t* nodes = nullptr;   // [size], the parent node at `level`
  int levels = 0;
  int level = 0;
  int64_t no_image = 0;

  bool HasImage(int64_t row) const { return images[row] != no_image; }
  uint32_t Parent(int64_t row) const { return static_cast<uint32_t>(nodes[row]); }
  int64_t Label(int64_t row) const { return labels[row * levels + level]; }
};

// Per row, the children a level's softmax ranges over, and the true child's column in them.
struct CandidateLists {
  std::vector<std::vector<int64_t>> children;
  std::vector<int64_t> target;
  size_t widest = 1;
};

// The rows with an image: the children the image sees, and the true child.
CandidateLists VisibleCandidates(const BatchContext& context, const LevelRows& rows) {
  const LabelTree& tree = context.tree;
  CandidateLists lists{std::vector<std::vector<int64_t>>(rows.size),
                       std::vector<int64_t>(rows.size, 0), 1};
  bool any_image = false;
  for (int64_t row = 0; row < rows.size; ++row) {
    if (!rows.HasImage(row)) continue;
    const uint32_t parent = rows.Parent(row);
    const uint32_t first = tree.FirstChild(parent);
    const int64_t truth = first + rows.Label(row);
    std::vector<int64_t>& candidates = lists.children[row];
    for (uint32_t c = 0; c < tree.NumChildren(parent); ++c) {
      if (first + c == truth ||
          context.masks->Contains(static_cast<int>(rows.images[row]), first + c)) {
        if (first + c == truth) lists.target[row] = static_cast<int64_t>(candidates.size());
        candidates.push_back(first + c);
      }
    }
    lists.widest = std::max(lists.widest, candidates.size());
    any_image = true;
  }
  if (!any_image) lists.widest = static_cast<size_t>(tree.branching());
  return lists;
}

// The rows without an image: the true child (column 0) and random siblings, as many candidates
// as the widest image row has.
void AddSampledSiblings(const BatchContext& context, const LevelRows& rows, int64_t iteration,
                        CandidateLists& lists) {
  const LabelTree& tree = context.tree;
  for (int64_t row = 0; row < rows.size; ++row) {
    if (rows.HasImage(row)) continue;
    const uint32_t parent = rows.Parent(row);
    const uint32_t first = tree.FirstChild(parent);
    const int64_t truth = first + rows.Label(row);
    std::vector<int64_t> siblings;
    for (uint32_t c = 0; c < tree.NumChildren(parent); ++c) {
      if (first + c != truth) siblings.push_back(first + c);
    }
    Random random(context.options.seed,
                  {kStreamSiblings, static_cast<uint64_t>(iteration), static_cast<uint64_t>(row),
                   static_cast<uint64_t>(rows.level)});
    const size_t keep = std::min(siblings.size(), lists.widest - 1);
    for (size_t i = 0; i < keep; ++i) {
      std::swap(siblings[i], siblings[i + random.UniformInt(siblings.size() - i)]);
    }
    lists.children[row] = {truth};
    lists.children[row].insert(lists.children[row].end(), siblings.begin(),
                               siblings.begin() + keep);
  }
}

// [size, widest] candidate node ids, -1 past a row's last candidate.
torch::Tensor CandidateTensor(const CandidateLists& lists, int64_t size) {
  torch::Tensor children =
      torch::full({size, static_cast<int64_t>(lists.widest)}, -1, torch::kInt64);
  int64_t* child_data = children.data_ptr<int64_t>();
  for (int64_t row = 0; row < size; ++row) {
    std::copy(lists.children[row].begin(), lists.children[row].end(),
              child_data + row * lists.widest);
  }
  return children;
}

// [size, branching]: the children the row's image sees (every child for a row without an image).
torch::Tensor AllowedChildren(const BatchContext& context, const LevelRows& rows) {
  const LabelTree& tree = context.tree;
  const int64_t branching = tree.branching();
  torch::Tensor allowed = torch::zeros({rows.size, branching}, torch::kBool);
  bool* allowed_data = allowed.data_ptr<bool>();
  for (int64_t row = 0; row < rows.size; ++row) {
    const uint32_t parent = rows.Parent(row);
    const uint32_t first = tree.FirstChild(parent);
    const int64_t count = tree.NumChildren(parent);
    const bool without_image = !rows.HasImage(row);
    for (int64_t c = 0; c < count; ++c) {
      allowed_data[row * branching + c] =
          without_image || context.masks->Contains(static_cast<int>(rows.images[row]), first + c);
    }
  }
  return allowed;
}

}  // namespace

uint32_t SampleOrder::At(uint64_t position) {
  const uint64_t epoch = position / samples_.size();
  if (epoch != epoch_) Shuffle(epoch);
  return permutation_[position % samples_.size()];
}

void SampleOrder::Shuffle(uint64_t epoch) {
  permutation_ = samples_;
  Random random(seed_, {kStreamShuffle, epoch});
  for (size_t i = permutation_.size(); i > 1; --i) {
    std::swap(permutation_[i - 1], permutation_[random.UniformInt(i)]);
  }
  epoch_ = epoch;
}

Batch MakeBatch(const BatchContext& context, SampleOrder& order, int64_t iteration,
                torch::Device device) {
  const LabelTree& tree = context.tree;
  const BatchRows drawn = DrawRows(context, order, iteration);
  Batch batch{drawn.descriptors.to(device),
              drawn.images.to(device),
              drawn.labels.to(device),
              {},
              {},
              {},
              {},
              {}};
  const int64_t size = context.options.batch_size;
  const int levels = tree.levels();
  std::vector<int64_t> node(size, 0);
  LevelRows rows{size,
                 drawn.images.data_ptr<int64_t>(),
                 drawn.labels.data_ptr<int64_t>(),
                 node.data(),
                 levels,
                 0,
                 static_cast<int64_t>(static_cast<uint32_t>(context.scene.NumImages()))};
  for (int level = 0; level < levels; ++level) {
    rows.level = level;
    torch::Tensor parents = torch::from_blob(node.data(), {size}, torch::kInt64).clone();
    torch::Tensor children, allowed, targets;
    FlatCandidates candidates;
    if (tree.LevelHasChoice(level) && context.point_candidates != nullptr) {
      std::vector<int> slots(size);
      for (int64_t row = 0; row < size; ++row) {
        slots[row] = context.point_candidates->SlotOf(drawn.source_images[row]);
      }
      candidates =
          GatherCandidates(*context.point_candidates, slots.data(), node.data(), 0, size, level,
                           /*allow_dense=*/true);
      std::vector<int64_t> true_ranks, true_rows;
      for (int64_t row = 0; row < size; ++row) {
        const auto [first, end] = context.point_candidates->RowsOfPoint(drawn.points[row]);
        for (uint32_t table_row = first; table_row < end; ++table_row) {
          true_ranks.push_back(table_row);
          true_rows.push_back(row);
        }
      }
      candidates.true_ranks = torch::tensor(true_ranks, torch::kInt64);
      candidates.true_rows = torch::tensor(true_rows, torch::kInt64);
      candidates.true_groups = drawn.labels.select(1, level).clone();
    } else if (tree.LevelHasChoice(level) && context.node_output && context.masks != nullptr) {
      // Only the candidates are gathered: the children the image sees (a few of up to
      // `branching`). A row without an image ranges over all children, sampled down to as many as
      // the widest image row has (the true child and random siblings), so that it costs no more.
      CandidateLists lists = VisibleCandidates(context, rows);
      AddSampledSiblings(context, rows, iteration, lists);
      children = CandidateTensor(lists, size).to(device);
      targets = torch::from_blob(lists.target.data(), {size}, torch::kInt64).clone().to(device);
    } else if (tree.LevelHasChoice(level)) {
      if (context.node_output) children = ChildNodesOf(tree, node.data(), size);
      if (context.masks != nullptr) allowed = AllowedChildren(context, rows).to(device);
      if (children.defined()) children = children.to(device);
    }
    batch.parent_nodes.push_back(parents.to(device));
    batch.child_nodes.push_back(children);
    batch.allowed.push_back(allowed);
    batch.targets.push_back(targets);
    batch.candidates.push_back(std::move(candidates));
    for (int64_t row = 0; row < size; ++row) {
      node[row] = tree.FirstChild(rows.Parent(row)) + rows.Label(row);
    }
  }
  return batch;
}

}  // namespace hscloc
