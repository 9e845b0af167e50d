// The CPU forward pass's row blocks (model/network_cpu_inference.cc): how rows are split into
// blocks over the compute threads, and each thread's working memory for one block. Internal to
// model/.
#pragma once

#include <algorithm>
#include <cstdint>
#include <functional>
#include <vector>

#include "model/network.h"
#include "util/parallel.h"

namespace hscloc::cpu_forward {

inline constexpr int64_t kRowBlock = 128;

// body(begin, end) over blocks of kRowBlock rows, on the compute threads.
inline void ForEachRowBlock(int64_t rows,
                            const std::function<void(int64_t begin, int64_t end)>& body) {
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
  // Pooled point rows: a chunk of gathered candidate rows.
  std::vector<float> gathered;
  // Where each child's candidates in the chunk begin (the last entry: the chunk's end), and that
  // child: candidates come in rank order, so a child's points are one run of the chunk.
  std::vector<uint32_t> segment_starts;
  std::vector<uint8_t> segment_groups;
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

}  // namespace hscloc::cpu_forward
