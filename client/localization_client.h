// The client side of the wire protocol (proto/hscloc.proto): building requests from plain arrays,
// and a connection with timeouts, retries and socket re-creation (zguide's Lazy Pirate) that
// fails over between several servers (zguide's Freelance, all servers active). Links protobuf and
// ZeroMQ only: no libtorch, FAISS or Ceres.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "proto/hscloc.pb.h"

namespace hscloc {

inline constexpr uint32_t kClientProtocolVersion = 1;

struct ClientOptions {
  // Equivalent endpoints (brokers, or servers of the same map), tried in this order: a request
  // goes to the current one, and moves to the next when its connection drops, when it refuses
  // connections, or when no reply came within timeout_ms.
  std::vector<std::string> servers = {"tcp://127.0.0.1:5555"};
  int timeout_ms = 10000;  // per attempt
  // Attempts after the first that may end in a timeout, each on the next server and a new
  // socket. Attempts cut short by a lost or refused connection move on at once and count only
  // against the whole call's bound, (retries + 1) * timeout_ms.
  int retries = 2;
  // CURVE: the server's public key turns encryption on; the client's key pair is generated when
  // left empty (then the server must accept any key), its public key derived from the secret one
  // when only that is given.
  std::string curve_server_key;
  std::string curve_public_key;
  std::string curve_secret_key;
};

// No reply after every attempt, or a reply that is not an hscloc Response.
class ClientError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// A COLMAP camera as text: "MODEL WIDTH HEIGHT PARAMS...", e.g. "SIMPLE_RADIAL 1024 768 995 512
// 384 0.13". Throws std::invalid_argument when malformed (the server checks the model).
wire::Camera ParseCamera(const std::string& text);

// A localize request from N keypoints (x, y pairs, pixels) and N x D row-major descriptors, packed
// little-endian; float16 halves the message for a small loss of precision.
wire::LocalizeRequest MakeLocalizeRequest(const std::string& query_name, const wire::Camera& camera,
                                          const std::vector<float>& keypoints_xy,
                                          const std::vector<float>& descriptors,
                                          uint32_t descriptor_dim, bool float16);

class LocalizationClient {
 public:
  explicit LocalizationClient(const ClientOptions& options);
  ~LocalizationClient();
  LocalizationClient(const LocalizationClient&) = delete;
  LocalizationClient& operator=(const LocalizationClient&) = delete;

  // Sends the request (its protocol version set here) and returns the reply. An attempt is given
  // up on when the server's connection drops or is refused, or no reply comes within the timeout:
  // the socket is closed, one to the next server connects, and the request is sent again
  // (Localize, Health and Info are idempotent); replies to abandoned attempts are discarded.
  // Reload changes the server's state and is never resent: its lost attempt is an error, and
  // Health tells which map the server ended up with. Throws ClientError when no attempt got a
  // reply.
  wire::Response Call(wire::Request request);

  // The server the next request goes to.
  const std::string& current_server() const { return options_.servers[current_]; }
  // Requests resent to another server so far (a measure of failovers).
  size_t failovers() const { return failovers_; }

  wire::LocalizeResponse Localize(const wire::LocalizeRequest& request);
  wire::HealthResponse Health();
  wire::InfoResponse Info();
  // Accepted on a server's admin endpoint (or with an admin CURVE key); the reply comes when the
  // reload is done.
  wire::ReloadResponse Reload();

 private:
  enum class Attempt { kAnswered, kTimedOut, kConnectionLost, kRefused };

  void Connect();
  // Sends one attempt of the call and waits for its reply; `reply` set when kAnswered.
  Attempt Send(const std::string& payload, std::chrono::milliseconds timeout,
               wire::Response& reply);
  // Moves to the next server, on a new socket.
  void FailOver();

  ClientOptions options_;
  struct State;
  std::unique_ptr<State> state_;
  size_t current_ = 0;
  uint64_t next_call_ = 0;
  size_t failovers_ = 0;
};

}  // namespace hscloc
