// The network's Linear weights in the CPU kernels' layout (dense_kernels::PackedMatrix), packed on
// first use and kept: a query's layers run over hundreds of row blocks, and packing per block
// costs as much as a small block's product.
#pragma once

#include <torch/torch.h>

#include <memory>
#include <mutex>
#include <unordered_map>

#include "model/dense_kernels.h"

namespace hscloc {

class PackedWeightCache {
 public:
  // The packed form of `weight` ([out, in], contiguous fp32 on the CPU). Packed again when the
  // tensor changed since: another storage or shape, or an in-place update (torch's version
  // counter: an optimizer step). Safe to call concurrently; the result stays valid for as long as
  // it is held, even when a later call packs a newer version.
  std::shared_ptr<const dense_kernels::PackedMatrix> Get(const torch::Tensor& weight);

  // Forgets every packed matrix (after the weights moved to another device and back, new storage
  // may reuse an old address at version 0).
  void Clear();

 private:
  struct Entry {
    int64_t version = 0;
    int64_t out_features = 0;
    int64_t in_features = 0;
    std::shared_ptr<const dense_kernels::PackedMatrix> packed;
  };
  std::mutex mutex_;
  std::unordered_map<const void*, Entry> entries_;
};

}  // namespace hscloc
