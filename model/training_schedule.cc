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
