#include "model/training_schedule.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace hscloc {

double TrainingBudget::Progress(int64_t iteration, double elapsed_seconds) const {
  double progress = 0;
  if (iterations > 0) progress = static_cast<double>(iteration) / static_cast<double>(iterations);
  if (seconds > 0) progress = std::max(progress, elapsed_seconds / seconds);
  return progress;
}

bool TrainingBudget::Spent(int64_t iteration, double elapsed_seconds) const {
  const int64_t max_iterations = iterations > 0 ? iterations : std::numeric_limits<int64_t>::max();
  return iteration >= max_iterations || (seconds > 0 && elapsed_seconds >= seconds);
}

TrainingBudget BudgetOf(const TrainerOptions& options, size_t num_training_observations) {
  const double num_training = static_cast<double>(num_training_observations);
  double epochs = options.epochs;
  if (options.max_iterations == 0 && options.max_minutes == 0 && epochs == 0) {
    epochs = DefaultEpochs(num_training_observations, options.network);
  }
  int64_t iterations = options.max_iterations;
  if (epochs > 0) {
    const auto from_epochs =
        static_cast<int64_t>(std::ceil(epochs * num_training / options.batch_size));
    iterations = iterations > 0 ? std::min(iterations, from_epochs) : from_epochs;
  }
  return {iterations, options.max_minutes * 60};
}

// The budget and widths a map gets when `hscloc train` is given none.
double DefaultEpochs(size_t num_training_observations, const NetworkOptions& network) {
  // Small maps need many passes (few views per point); large ones fewer, each pass being longer.
  const double n = std::max<double>(1, static_cast<double>(num_training_observations));
  if (network.pooled_point_rows) return std::clamp(3.0 * std::sqrt(1e6 / n), 1.5, 400.0);
  return std::clamp(12.0 * std::sqrt(1e6 / n), 10.0, 400.0);
}

NetworkOptions DefaultNetworkOptions(size_t num_points, int descriptor_dim) {
  NetworkOptions options;
  // A map of a few thousand points has about three views of each: a network learned from them
  // alone fell far behind the points' mean descriptors on held-out views (Lund XFeat 42 % against
  // 75 %). The shortcut starts as those means and only keeps what training improves; at C = H = 128
  // it is 7 times smaller and trains 5 to 10 times faster than C = 512 with a shared output layer,
  // with poses as good over seeds (docs/decisions.md, "The network on real photos").
  if (num_points < kMinPointsForNodeOutputRows) {
    options.channels = kSmallMapChannels;
    options.trunk_channels = kSmallMapChannels;
    options.node_output_dim = descriptor_dim;
    options.pooled_point_rows = true;
    options.descriptor_shortcut = true;
    options.node_conditioning = DefaultNodeConditioning(options);
    return options;
  }
  // The node output rows are most of the network's bytes: at most about 6 M numbers (24 MB), so
  // that the HSC bundle stays under a fifth of the nearest-neighbour map (docs/decisions.md).
  int rows = 64;
  while (rows > 16 && static_cast<double>(num_points) * (rows + 1) > 6e6) rows /= 2;
  options.node_output_dim = rows;
  options.pooled_point_rows = true;
  options.node_conditioning = DefaultNodeConditioning(options);
  // At C = H = 512 the trunks were most of a query's work (docs/decisions.md, "Latency at Aachen
  // scale"); the small maps' C = H = 128 trunks are not.
  options.shared_trunk = true;
  return options;
}

int DefaultPointPrototypes(const NetworkOptions& network) {
  return network.descriptor_shortcut ? kMaxPointPrototypes : 1;
}

bool DefaultNodeConditioning(const NetworkOptions& options) {
  // Pooled point rows score a child through its own points, which already tell parents apart;
  // a node table beside them is most of a large network's bytes (two thirds on the aachen
  // preset) and moved no held-out accuracy measurably (docs/decisions.md).
  return !options.pooled_point_rows;
}

double ScheduledLearningRate(const TrainerOptions& options, double progress) {
  if (options.schedule == LearningRateSchedule::kOneCycle) {
    const double peak = options.learning_rate;
    const double warmup = options.warmup_fraction;
    if (progress < warmup) return peak * (0.1 + 0.9 * progress / warmup);
    const double t = std::min(1.0, (progress - warmup) / std::max(1e-9, 1 - warmup));
    const double low = peak * options.final_rate_fraction;
    return low + (peak - low) * 0.5 * (1 + std::cos(M_PI * t));
  }
  double rate = options.learning_rate;
  for (const double fraction : options.halving_fractions) {
    if (progress >= fraction) rate *= 0.5;
  }
  return rate;
}

}  // namespace hscloc
