// The trainer's budget and learning-rate schedule (model/trainer.cc); training_schedule.cc also
// defines the defaults a map gets from its size (declared in model/trainer.h). Private to
// model/: nothing outside model/ includes this header.
#pragma once

#include <cstddef>
#include <cstdint>

#include "model/trainer.h"

namespace hscloc {

// Training stops at whichever of the iterations and the time is spent first.
struct TrainingBudget {
  int64_t iterations = 0;  // 0: no limit
  double seconds = 0;      // 0: no limit

  // The fraction of the budget spent after `iteration` iterations and `elapsed_seconds`: the
  // larger of the two fractions.
  double Progress(int64_t iteration, double elapsed_seconds) const;
  bool Spent(int64_t iteration, double elapsed_seconds) const;
};

// The options' budget: iterations, minutes, epochs (the fewest iterations of those given), or
// (none given) the automatic epochs of DefaultEpochs.
TrainingBudget BudgetOf(const TrainerOptions& options, size_t num_training_observations);

// The learning rate at `progress` (fraction of the budget) of the options' schedule.
double ScheduledLearningRate(const TrainerOptions& options, double progress);

}  // namespace hscloc
