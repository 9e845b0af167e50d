#include "server/reload_coalescer.h"

#include <future>
#include <memory>

namespace hscloc {

ReloadCoalescer::ReloadCoalescer(Reload reload) : reload_(std::move(reload)) {
  thread_ = std::thread([this] { Loop(); });
}

ReloadCoalescer::~ReloadCoalescer() { Stop(); }

bool ReloadCoalescer::Request(Done done) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (stopping_) return false;
    waiting_.push_back(std::move(done));
  }
  wake_.notify_one();
  return true;
}

ReloadOutcome ReloadCoalescer::RequestAndWait() {
  auto promise = std::make_shared<std::promise<ReloadOutcome>>();
  std::future<ReloadOutcome> outcome = promise->get_future();
  if (!Request([promise](const ReloadOutcome& done) { promise->set_value(done); })) {
    ReloadOutcome cancelled;
    cancelled.cancelled = true;
    cancelled.error_message = "the server is shutting down";
    return cancelled;
  }
  return outcome.get();
}

void ReloadCoalescer::Stop() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  wake_.notify_one();
  if (thread_.joinable()) thread_.join();
}

size_t ReloadCoalescer::reloads_executed() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return executed_;
}

bool ReloadCoalescer::stopped() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return stopped_;
}

void ReloadCoalescer::Loop() {
  while (true) {
    std::vector<Done> batch;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      wake_.wait(lock, [&] { return stopping_ || !waiting_.empty(); });
      batch.swap(waiting_);
      if (stopping_) {
        // The requests still waiting are answered here, on the thread that answers every other.
        ReloadOutcome cancelled;
        cancelled.cancelled = true;
        cancelled.error_message = "the server is shutting down";
        lock.unlock();
        for (const Done& done : batch) done(cancelled);
        lock.lock();
        stopped_ = true;
        return;
      }
      ++executed_;
    }
    const ReloadOutcome outcome = reload_();
    for (const Done& done : batch) done(outcome);
  }
}

}  // namespace hscloc
