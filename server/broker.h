// The broker of a scaled-out deployment (zguide's Paranoid Pirate, with credits): clients connect
// to its front ROUTER exactly as to a single server; worker processes (`hscloc serve --connect`)
// connect to its back ROUTER, announce how many requests they take at once, and exchange
// heartbeats with it. Requests wait in a bounded queue until a worker has a free slot; a worker
// that misses its heartbeats is dropped and the requests it held go to another worker, so a
// crashed worker loses no request.
#pragma once

#include <atomic>
#include <chrono>
#include <string>
#include <thread>

namespace hscloc {

// Control messages between broker and workers are single frames; requests and replies always
// have an envelope and a payload (two frames or more).
inline constexpr char kWorkerReady[] = "\x01READY";  // followed by the slot count
inline constexpr char kHeartbeat[] = "\x01HEARTBEAT";

struct BrokerOptions {
  std::string front = "tcp://*:5555";  // clients
  std::string back = "tcp://*:5556";   // workers
  size_t max_queue = 256;              // waiting requests beyond which OVERLOADED is answered
  std::chrono::milliseconds heartbeat_interval{500};
  int heartbeat_liveness = 4;  // missed heartbeats after which a worker is dropped

  void Check() const;
};

class Broker {
 public:
  explicit Broker(const BrokerOptions& options);
  ~Broker();
  Broker(const Broker&) = delete;
  Broker& operator=(const Broker&) = delete;

  // Binds both sockets and starts the broker's thread; returns the bound front and back endpoints.
  std::pair<std::string, std::string> Start();
  // Stops forwarding and closes the sockets. Idempotent.
  void Stop();

  size_t requests_retried() const { return retried_.load(); }
  size_t workers_dropped() const { return dropped_.load(); }

 private:
  void Loop();

  BrokerOptions options_;
  struct State;
  std::unique_ptr<State> state_;
  std::thread thread_;
  std::atomic<bool> stopping_{false};
  std::atomic<size_t> retried_{0};
  std::atomic<size_t> dropped_{0};
};

}  // namespace hscloc
