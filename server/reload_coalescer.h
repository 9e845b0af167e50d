// Reloads one at a time on one thread of their own, however many are asked for. A request that
// arrives while a reload runs joins the single reload that starts after it (the running one may
// have read the map directory before the request's new map was moved in), so a burst of requests
// costs at most two reloads and one thread. Stop waits for the running reload only: the waiting
// ones are cancelled.
#pragma once

#include <condition_variable>
#include <functional>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

namespace hscloc {

struct ReloadOutcome {
  bool success = false;
  bool cancelled = false;  // the reload never ran: the server stopped first
  std::string error_message;
  std::string map_id;
};

class ReloadCoalescer {
 public:
  using Reload = std::function<ReloadOutcome()>;
  using Done = std::function<void(const ReloadOutcome&)>;

  // Starts the reload thread; `reload` runs on it, never twice at once.
  explicit ReloadCoalescer(Reload reload);
  ~ReloadCoalescer();
  ReloadCoalescer(const ReloadCoalescer&) = delete;
  ReloadCoalescer& operator=(const ReloadCoalescer&) = delete;

  // Calls `done` on the reload thread with the outcome of a reload that starts after this call
  // (or a cancelled outcome when Stop comes first). Returns false, without calling `done`, once
  // stopped.
  bool Request(Done done);
  // Request, then waits for the outcome.
  ReloadOutcome RequestAndWait();
  // Cancels the waiting requests and returns when the running reload, if any, is done.
  // Idempotent.
  void Stop();

  size_t reloads_executed() const;
  bool stopped() const;

 private:
  void Loop();

  Reload reload_;
  mutable std::mutex mutex_;
  std::condition_variable wake_;
  std::vector<Done> waiting_;  // for the next reload
  size_t executed_ = 0;
  bool stopping_ = false;
  bool stopped_ = false;
  std::thread thread_;
};

}  // namespace hscloc
