// The broker of a scaled-out deployment (zguide's Paranoid Pirate, with credits): clients connect
// to its front ROUTER exactly as to a single server; worker processes (`hscloc serve --connect`)
// connect to its back ROUTER, announce how many requests they take at once, and exchange
// heartbeats with it. Requests wait in a bounded queue until a worker has a free slot; a worker
// whose connection closes, or that misses its heartbeats, is dropped and the requests it held go
// to another worker, so a crashed worker loses no request.
//
// With CURVE the front admits clients as a single server does (the server's key, an allow-list of
// client keys) and the back admits only the workers whose keys are on its own allow-list, so no
// stranger receives the clients' requests. The admin endpoint answers the broker's own Health
// (ready while at least one worker heartbeats), for its probes.
#pragma once

#include <atomic>
#include <chrono>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "server/metrics.h"

namespace hscloc {

// Control messages between broker and workers are single frames; requests and replies always
// have an envelope and a payload (two frames or more).
// Followed by the slot count, a space and the id of the map the worker serves.
inline constexpr char kWorkerReady[] = "\x01READY";
inline constexpr char kHeartbeat[] = "\x01HEARTBEAT";

struct BrokerOptions {
  std::string front = "tcp://*:5555";  // clients
  std::string back = "tcp://*:5556";   // workers
  // The broker's own Health; loopback or ipc:// (ServiceOptions.admin_bind). Empty: none.
  std::string admin_bind = "tcp://127.0.0.1:5557";
  // Prometheus metrics ("host:port"; ServiceOptions.metrics_bind). Empty: not exposed.
  std::string metrics_bind;
  size_t max_queue = 256;  // waiting requests beyond which OVERLOADED is answered
  std::chrono::milliseconds heartbeat_interval{500};
  int heartbeat_liveness = 4;  // missed heartbeats after which a worker is dropped
  // CURVE (Z85 keys): the front's secret key and the clients it admits (empty: any client with
  // the front's public key), as ServiceOptions; the back's own secret key and the workers it
  // admits (required with a back key: a worker is trusted with the clients' requests).
  std::string curve_secret_key;
  std::vector<std::string> curve_allowed_client_keys;
  std::string backend_curve_secret_key;
  std::vector<std::string> curve_allowed_worker_keys;

  void Check() const;
};

class Broker {
 public:
  explicit Broker(const BrokerOptions& options);
  ~Broker();
  Broker(const Broker&) = delete;
  Broker& operator=(const Broker&) = delete;

  // Binds the sockets and starts the broker's thread; returns the bound front and back endpoints.
  std::pair<std::string, std::string> Start();
  // The admin endpoint as bound (its real port), or empty when there is none.
  const std::string& admin_endpoint() const { return admin_endpoint_; }
  // The metrics' URL as bound, or empty when they are not exposed.
  std::string metrics_url() const { return metrics_ == nullptr ? "" : metrics_->url(); }
  // Stops forwarding and closes the sockets. Idempotent.
  void Stop();

  size_t requests_retried() const { return retried_.load(); }
  size_t workers_dropped() const { return dropped_.load(); }
  size_t workers_joined() const { return joined_.load(); }

 private:
  struct State;

  using Clock = std::chrono::steady_clock;
  static constexpr std::chrono::milliseconds kProbeInterval{20};

  void OpenSockets();
  // Polls the sockets until Stop(): each round receives, requeues the requests of silent
  // workers, dispatches, publishes the gauges and sends heartbeats.
  void Loop();
  void ReceiveFromWorker(Clock::time_point now);  // a heartbeat or a reply
  void NoteClosedConnection(Clock::time_point now);
  // Sends to the worker the first frame names; false (and the worker dropped in this round) when
  // its connection is gone.
  bool SendToWorker(const std::vector<std::string>& frames);
  void ReceiveFromClient();  // queued, or refused when the queue is full
  void RequeueSilentWorkers(Clock::time_point now);
  void DispatchWaiting();
  void PublishGauges();
  void AnswerAdmin();

  BrokerOptions options_;
  std::unique_ptr<BrokerMetrics> metrics_;
  std::unique_ptr<State> state_;
  std::string admin_endpoint_;
  double started_s_ = 0;
  std::thread thread_;
  std::atomic<bool> stopping_{false};
  std::atomic<size_t> retried_{0};
  std::atomic<size_t> dropped_{0};
  std::atomic<size_t> joined_{0};
};

}  // namespace hscloc
