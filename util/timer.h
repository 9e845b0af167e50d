// Wall-clock timing for stage timings and logs.
#pragma once

#include <chrono>
#include <string>

namespace hscloc {

class Timer {
 public:
  Timer() : start_(Clock::now()) {}
  void Restart() { start_ = Clock::now(); }
  double ElapsedSeconds() const {
    return std::chrono::duration<double>(Clock::now() - start_).count();
  }
  double ElapsedMilliseconds() const { return 1e3 * ElapsedSeconds(); }

 private:
  using Clock = std::chrono::steady_clock;
  Clock::time_point start_;
};

// Adds the elapsed milliseconds of its scope to *accumulated_ms when it ends (also on an
// exception), so a stage's time is recorded however the stage exits.
class ScopedTimer {
 public:
  explicit ScopedTimer(double* accumulated_ms) : accumulated_ms_(accumulated_ms) {}
  ~ScopedTimer() { *accumulated_ms_ += timer_.ElapsedMilliseconds(); }
  ScopedTimer(const ScopedTimer&) = delete;
  ScopedTimer& operator=(const ScopedTimer&) = delete;

 private:
  double* accumulated_ms_;
  Timer timer_;
};

// Formats a duration for people: "850 ms", "12.3 s", "4 min 05 s", "2 h 03 min".
std::string FormatDuration(double seconds);

}  // namespace hscloc
