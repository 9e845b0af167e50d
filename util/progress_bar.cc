#include "util/progress_bar.h"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>

namespace hscloc {
namespace {

constexpr double kRedrawIntervalS = 0.1;
// Without a terminal (CI, services, pipes) the state goes out as a plain log line this often, so
// that long work still shows it is moving without flooding the log.
constexpr double kLogIntervalS = 15.0;
constexpr int kBarWidth = 24;

bool IsTerminal(ProgressBar::Display display) {
  return display == ProgressBar::Display::kAlways ||
         (display == ProgressBar::Display::kAuto && isatty(fileno(stderr)) == 1);
}

bool ShouldDraw(ProgressBar::Display display) {
  switch (display) {
    case ProgressBar::Display::kAlways:
      return true;
    case ProgressBar::Display::kNever:
      return false;
    case ProgressBar::Display::kAuto:
      break;
  }
  return true;
}

std::string FormatCount(double value) {
  if (value >= 1e9) return fmt::format("{:.2f}G", value / 1e9);
  if (value >= 1e6) return fmt::format("{:.2f}M", value / 1e6);
  if (value >= 1e4) return fmt::format("{:.1f}k", value / 1e3);
  return fmt::format("{:.0f}", value);
}

}  // namespace

ProgressBar::ProgressBar(std::string label, uint64_t total, Display display)
    : label_(std::move(label)),
      total_(total),
      draw_(ShouldDraw(display)),
      redraw_(IsTerminal(display)) {
  if (!redraw_) next_draw_s_ = kLogIntervalS;
}

ProgressBar::~ProgressBar() { Finish(); }

void ProgressBar::Advance(uint64_t units) {
  done_.fetch_add(units, std::memory_order_relaxed);
  if (!draw_) return;
  const double now_s = timer_.ElapsedSeconds();
  double next_s = next_draw_s_.load(std::memory_order_relaxed);
  // One thread wins the redraw slot; the others return at once instead of queueing on the lock.
  if (now_s >= next_s && next_draw_s_.compare_exchange_strong(
                             next_s, now_s + (redraw_ ? kRedrawIntervalS : kLogIntervalS))) {
    Draw(false);
  }
}

void ProgressBar::SetStatus(std::string status) {
  std::lock_guard<std::mutex> lock(mutex_);
  status_ = std::move(status);
}

void ProgressBar::Finish() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (finished_) return;
  }
  if (draw_) Draw(true);
  std::lock_guard<std::mutex> lock(mutex_);
  finished_ = true;
}

void ProgressBar::SetTimeLimit(double seconds) {
  time_limit_s_.store(std::max(0.0, seconds), std::memory_order_relaxed);
}

std::string ProgressBar::Render() const {
  const uint64_t done = done_.load(std::memory_order_relaxed);
  const double elapsed_s = timer_.ElapsedSeconds();
  const double time_limit_s = time_limit_s_.load(std::memory_order_relaxed);
  const double rate = elapsed_s > 0 ? done / elapsed_s : 0.0;
  // Whichever of the units and the time limit ends the work first sets the fraction and the ETA.
  double fraction = 0;
  double remaining_s = -1;
  if (total_ > 0) {
    fraction = std::min(1.0, static_cast<double>(done) / total_);
    if (done > 0 && done < total_) remaining_s = (total_ - done) / rate;
  }
  if (time_limit_s > 0) {
    fraction = std::max(fraction, std::min(1.0, elapsed_s / time_limit_s));
    const double left_s = std::max(0.0, time_limit_s - elapsed_s);
    remaining_s = remaining_s < 0 ? left_s : std::min(remaining_s, left_s);
  }
  std::string line = label_;
  if (total_ > 0 || time_limit_s > 0) {
    const int filled = static_cast<int>(fraction * kBarWidth);
    line += fmt::format(" [{}{}] {:3.0f}% {}", std::string(filled, '#'),
                        std::string(kBarWidth - filled, '.'), 100 * fraction, FormatCount(done));
    if (total_ > 0) line += "/" + FormatCount(total_);
  } else {
    line += fmt::format(" {}", FormatCount(done));
  }
  line += fmt::format(" {}/s {}", FormatCount(rate), FormatDuration(elapsed_s));
  if (remaining_s > 0 && fraction < 1) line += fmt::format(" ETA {}", FormatDuration(remaining_s));
  std::lock_guard<std::mutex> lock(mutex_);
  if (!status_.empty()) line += " " + status_;
  return line;
}

void ProgressBar::Draw(bool final) {
  const std::string line = Render();
  std::lock_guard<std::mutex> lock(mutex_);
  if (finished_) return;
  if (redraw_) {
    // \033[K clears what a longer previous line left behind.
    std::fprintf(stderr, "\r%s\033[K%s", line.c_str(), final ? "\n" : "");
  } else {
    std::fprintf(stderr, "%s\n", line.c_str());
  }
  std::fflush(stderr);
}

}  // namespace hscloc
