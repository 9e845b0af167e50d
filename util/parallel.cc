#include "util/parallel.h"

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <deque>
#include <exception>
#include <memory>
#include <mutex>
#include <system_error>
#include <thread>

namespace hscloc {
namespace {

// One ParallelFor call's chunks. Shared with the pool's threads, which may reach a call's helper
// task only after the caller returned: a helper that finds no chunk left never touches `body`.
struct LoopState {
  LoopState(size_t count, size_t chunk, const std::function<void(size_t, size_t)>& body)
      : count(count), chunk(chunk), body(&body) {}

  const size_t count;
  const size_t chunk;
  const std::function<void(size_t, size_t)>* body;
  std::atomic<size_t> next{0};
  std::atomic<bool> failed{false};
  std::exception_ptr first_error;  // written once, under `mutex`
  std::mutex mutex;
  std::condition_variable all_done;
  size_t done = 0;  // items finished or skipped, under `mutex`

  // Runs chunks until none is left. Every claimed chunk counts as done, skipped after a failure,
  // so the caller's wait always ends.
  void RunChunks() {
    for (;;) {
      const size_t begin = next.fetch_add(chunk);
      if (begin >= count) return;
      const size_t end = std::min(count, begin + chunk);
      std::exception_ptr error;
      if (!failed.load(std::memory_order_relaxed)) {
        try {
          (*body)(begin, end);
        } catch (...) {
          error = std::current_exception();
          failed.store(true, std::memory_order_relaxed);
        }
      }
      std::lock_guard<std::mutex> lock(mutex);
      if (error && !first_error) first_error = error;
      done += end - begin;
      if (done == count) all_done.notify_all();
    }
  }

  void WaitUntilDone() {
    std::unique_lock<std::mutex> lock(mutex);
    all_done.wait(lock, [&] { return done == count; });
  }
};

// Threads kept for the life of the process: starting a thread per loop costs tens to hundreds of
// microseconds, and a fresh thread's thread_local working memory (the network's row blocks) is
// allocated and faulted in again on every call. A caller always works through its own loop too,
// so a loop finishes even when every pool thread is busy (nested loops, several callers).
class ThreadPool {
 public:
  static ThreadPool& Instance() {
    // Never destroyed: its threads may still wait for work while static objects are torn down.
    static ThreadPool* pool = new ThreadPool();
    return *pool;
  }

  // Queues up to `helpers` tasks that each run the loop's chunks, starting threads up to that
  // many. Where the system refuses a thread, the loop gets the threads there are: its caller does
  // the rest.
  void Help(const std::shared_ptr<LoopState>& loop, size_t helpers) {
    std::lock_guard<std::mutex> lock(mutex_);
    while (started_threads_ < helpers) {
      try {
        std::thread([this] { Serve(); }).detach();
      } catch (const std::system_error&) {
        break;
      }
      ++started_threads_;
    }
    helpers = std::min(helpers, started_threads_);
    for (size_t i = 0; i < helpers; ++i) tasks_.push_back(loop);
    if (helpers == 1) {
      work_ready_.notify_one();
    } else {
      work_ready_.notify_all();
    }
  }

 private:
  void Serve() {
    for (;;) {
      std::shared_ptr<LoopState> loop;
      {
        std::unique_lock<std::mutex> lock(mutex_);
        work_ready_.wait(lock, [&] { return !tasks_.empty(); });
        loop = std::move(tasks_.front());
        tasks_.pop_front();
      }
      loop->RunChunks();
    }
  }

  std::mutex mutex_;
  std::condition_variable work_ready_;
  std::deque<std::shared_ptr<LoopState>> tasks_;
  size_t started_threads_ = 0;
};

}  // namespace

int ResolveNumThreads(int requested) {
  if (requested > 0) return requested;
  return std::max(1u, std::thread::hardware_concurrency());
}

void ParallelFor(size_t count, int num_threads,
                 const std::function<void(size_t begin, size_t end)>& body) {
  if (count == 0) return;
  const size_t threads = std::min<size_t>(ResolveNumThreads(num_threads), count);
  if (threads == 1) {
    body(0, count);
    return;
  }
  // Small chunks handed out dynamically balance uneven work (images with many points).
  const size_t chunk = std::max<size_t>(1, count / (threads * 8));
  const auto loop = std::make_shared<LoopState>(count, chunk, body);
  ThreadPool::Instance().Help(loop, threads - 1);
  loop->RunChunks();
  loop->WaitUntilDone();
  if (loop->first_error) std::rethrow_exception(loop->first_error);
}

}  // namespace hscloc
