#include "model/packed_weight_cache.h"

#include <stdexcept>

namespace hscloc {

std::shared_ptr<const dense_kernels::PackedMatrix> PackedWeightCache::Get(
    const torch::Tensor& weight) {
  if (!weight.device().is_cpu() || weight.scalar_type() != torch::kFloat32 ||
      !weight.is_contiguous() || weight.dim() != 2) {
    throw std::logic_error("PackedWeightCache: not a contiguous fp32 CPU matrix");
  }
  const int64_t version = weight._version();
  const int64_t out_features = weight.size(0);
  const int64_t in_features = weight.size(1);
  const std::lock_guard<std::mutex> lock(mutex_);
  Entry& entry = entries_[weight.data_ptr()];
  if (entry.packed == nullptr || entry.version != version || entry.out_features != out_features ||
      entry.in_features != in_features) {
    entry = {version, out_features, in_features,
             std::make_shared<const dense_kernels::PackedMatrix>(
                 dense_kernels::PackMatrix(weight.data_ptr<float>(), out_features, in_features))};
  }
  return entry.packed;
}

void PackedWeightCache::Clear() {
  const std::lock_guard<std::mutex> lock(mutex_);
  entries_.clear();
}

}  // namespace hscloc
