// A progress bar for long loops: count, rate and ETA on one redrawn line of stderr when stderr is
// a terminal (or when forced); elsewhere (CI, services, pipes) the same text as a plain line every
// 15 s and at the end, so logs show long work moving without filling up. Advance() is
// thread-safe and cheap enough for per-item calls from worker threads.
#pragma once

#include <atomic>
#include <cstdint>
#include <mutex>
#include <string>

#include "util/timer.h"

namespace hscloc {

class ProgressBar {
 public:
  enum class Display { kAuto, kAlways, kNever };

  // total: the number of units of work (0 when unknown: no percentage or ETA is shown).
  ProgressBar(std::string label, uint64_t total, Display display = Display::kAuto);
  ~ProgressBar();
  ProgressBar(const ProgressBar&) = delete;
  ProgressBar& operator=(const ProgressBar&) = delete;

  void Advance(uint64_t units = 1);
  // The work also ends after this many seconds from the bar's start (a time budget): percentage
  // and ETA then follow whichever of the two ends first. <= 0: no time limit (the default).
  void SetTimeLimit(double seconds);
  // Sets a short status shown after the counters (a loss, an accuracy).
  void SetStatus(std::string status);
  // Draws the final state and ends the line; called by the destructor if not before.
  void Finish();

  uint64_t done() const { return done_.load(std::memory_order_relaxed); }
  bool drawing() const { return draw_; }

  // The line as it would be drawn now, without the carriage return; for tests and logs.
  std::string Render() const;

 private:
  void Draw(bool final);

  const std::string label_;
  const uint64_t total_;
  const bool draw_;
  const bool redraw_;  // redraw one line (a terminal) rather than log whole lines
  std::atomic<uint64_t> done_{0};
  std::atomic<double> next_draw_s_{0.0};
  std::atomic<double> time_limit_s_{0.0};
  mutable std::mutex mutex_;
  std::string status_;
  bool finished_ = false;
  Timer timer_;
};

}  // namespace hscloc
