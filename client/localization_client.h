// The client side of the wire protocol (proto/hscloc.proto): building requests from plain arrays,
// and a connection with timeouts, retries and socket re-creation (zguide's Lazy Pirate). Links
// protobuf and ZeroMQ only: no libtorch, FAISS or Ceres.
#pragma once

#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "proto/hscloc.pb.h"

namespace hscloc {

inline constexpr uint32_t kClientProtocolVersion = 1;

struct ClientOptions {
  std::string server = "tcp://127.0.0.1:5555";
  int timeout_ms = 10000;  // per attempt
  int retries = 2;         // attempts after the first, each on a new socket
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

  // Sends the request (its protocol version set here) and returns the reply. A reply that does not
  // come within the timeout is given up on: the socket is closed, a new one connects, and the
  // request is sent again, up to `retries` times; replies to abandoned attempts are discarded.
  // Throws ClientError when every attempt timed out.
  wire::Response Call(wire::Request request);

  wire::LocalizeResponse Localize(const wire::LocalizeRequest& request);
  wire::HealthResponse Health();
  wire::InfoResponse Info();
  // Accepted on a server's admin endpoint (or with an admin CURVE key); the reply comes when the
  // reload is done.
  wire::ReloadResponse Reload();

 private:
  void Connect();

  ClientOptions options_;
  struct State;
  std::unique_ptr<State> state_;
  uint64_t next_call_ = 0;
};

}  // namespace hscloc
