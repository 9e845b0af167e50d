#include "model/lazy_adam.h"

#include <cmath>

namespace hscloc {

LazyAdamTable LazyAdamTable::Of(const torch::Tensor& parameter) {
  return {parameter, torch::zeros_like(parameter), torch::zeros_like(parameter), 0};
}

void LazyAdamTable::Step(double learning_rate) {
  const torch::Tensor gradient = parameter.grad();
  if (!gradient.defined()) return;
  torch::NoGradGuard no_grad;
  ++steps;
  constexpr double kBeta1 = 0.9, kBeta2 = 0.999, kEpsilon = 1e-8;
  torch::Tensor rows, values;
  if (gradient.is_sparse()) {
    const torch::Tensor coalesced = gradient.coalesce();
    rows = coalesced.indices().select(0, 0);
    values = coalesced.values();
  } else {
    rows = gradient.abs().sum(1).nonzero().squeeze(1);
    values = gradient.index_select(0, rows);
  }
  const torch::Tensor m = first_moment.index_select(0, rows).mul_(kBeta1).add_(values, 1 - kBeta1);
  const torch::Tensor v =
      second_moment.index_select(0, rows).mul_(kBeta2).addcmul_(values, values, 1 - kBeta2);
  first_moment.index_copy_(0, rows, m);
  second_moment.index_copy_(0, rows, v);
  const double correction1 = 1 - std::pow(kBeta1, static_cast<double>(steps));
  const double correction2 = 1 - std::pow(kBeta2, static_cast<double>(steps));
  const torch::Tensor update =
      m / (v / correction2).sqrt_().add_(kEpsilon) * (learning_rate / correction1);
  parameter.index_add_(0, rows, update.neg_());
  parameter.mutable_grad() = torch::Tensor();
}

}  // namespace hscloc
