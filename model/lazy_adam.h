// Row-wise lazy Adam for the trainer's node output rows (model/trainer.cc). Private to model/: it
// holds libtorch types, and nothing outside model/ includes this header.
#pragma once

#include <torch/torch.h>

#include <cstdint>

namespace hscloc {

// Adam on the rows of a table that a step's sparse gradient touches (PyTorch's SparseAdam): the
// other rows and their moments stay as they are.
struct LazyAdamTable {
  torch::Tensor parameter, first_moment, second_moment;
  int64_t steps = 0;

  // A table with zero moments, as Adam starts.
  static LazyAdamTable Of(const torch::Tensor& parameter);
  // One Adam step (beta1 0.9, beta2 0.999, epsilon 1e-8) on the rows the gradient touches; clears
  // the gradient. Does nothing when there is no gradient.
  void Step(double learning_rate);
};

}  // namespace hscloc
