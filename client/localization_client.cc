#include "client/localization_client.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <cmath>
#include <cstring>
#include <sstream>
#include <thread>
#include <zmq.hpp>
#include <zmq_addon.hpp>

namespace hscloc {
namespace {

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "the wire format is little-endian");

// IEEE 754 binary32 -> binary16, rounding to nearest even; overflow becomes infinity.
uint16_t ToHalf(float value) {
  uint32_t bits;
  std::memcpy(&bits, &value, 4);
  const uint32_t sign = (bits >> 16) & 0x8000;
  const int32_t exponent = static_cast<int32_t>((bits >> 23) & 0xff) - 127 + 15;
  uint32_t mantissa = bits & 0x7fffff;
  if (((bits >> 23) & 0xff) == 0xff) {  // infinity or NaN
    return static_cast<uint16_t>(sign | 0x7c00 | (mantissa ? 0x200 : 0));
  }
  if (exponent >= 31) return static_cast<uint16_t>(sign | 0x7c00);
  if (exponent <= 0) {  // subnormal half or zero
    if (exponent < -10) return static_cast<uint16_t>(sign);
    mantissa |= 0x800000;
    const int shift = 14 - exponent;
    uint32_t half = mantissa >> shift;
    const uint32_t rest = mantissa & ((1u << shift) - 1);
    const uint32_t halfway = 1u << (shift - 1);
    if (rest > halfway || (rest == halfway && (half & 1))) ++half;
    return static_cast<uint16_t>(sign | half);
  }
  uint32_t half = (static_cast<uint32_t>(exponent) << 10) | (mantissa >> 13);
  const uint32_t rest = mantissa & 0x1fff;
  if (rest > 0x1000 || (rest == 0x1000 && (half & 1))) ++half;  // may carry into the exponent
  return static_cast<uint16_t>(sign | half);
}

}  // namespace

struct LocalizationClient::State {
  zmq::context_t context{1};
  zmq::socket_t socket;
  // The socket's connection events (zmq_socket_monitor), so that a server that dies or refuses
  // connections is left at once rather than after the timeout.
  zmq::socket_t monitor;
  uint64_t generation = 0;  // names each socket's monitor endpoint
  // Whether the socket ever completed a handshake with its server: a connection that drops after
  // that lost a server that was there; one refused at the handshake (a CURVE key the server does
  // not admit) is reconnected by ZeroMQ and only the timeout gives up on it, as before.
  bool connected = false;
  bool handshaken = false;
};

wire::Camera ParseCamera(const std::string& text) {
  std::istringstream fields(text);
  wire::Camera camera;
  std::string model;
  int64_t width = 0;
  int64_t height = 0;
  if (!(fields >> model >> width >> height) || width <= 0 || height <= 0) {
    throw std::invalid_argument(
        fmt::format("camera '{}': expected \"MODEL WIDTH HEIGHT PARAMS...\"", text));
  }
  camera.set_model(model);
  camera.set_width(static_cast<uint32_t>(width));
  camera.set_height(static_cast<uint32_t>(height));
  for (std::string token; fields >> token;) {
    try {
      size_t used = 0;
      camera.add_params(std::stod(token, &used));
      if (used != token.size()) throw std::invalid_argument(token);
    } catch (const std::exception&) {
      throw std::invalid_argument(fmt::format("camera '{}': '{}' is not a number", text, token));
    }
  }
  return camera;
}

wire::LocalizeRequest MakeLocalizeRequest(const std::string& query_name, const wire::Camera& camera,
                                          const std::vector<float>& keypoints_xy,
                                          const std::vector<float>& descriptors,
                                          uint32_t descriptor_dim, bool float16) {
  if (keypoints_xy.size() % 2 != 0 || descriptor_dim == 0 ||
      descriptors.size() != keypoints_xy.size() / 2 * descriptor_dim) {
    throw std::invalid_argument(fmt::format(
        "{}: {} keypoint coordinates and {} descriptor values do not make N x 2 and N x {}",
        query_name, keypoints_xy.size(), descriptors.size(), descriptor_dim));
  }
  wire::LocalizeRequest request;
  request.set_request_id(query_name);
  request.set_query_name(query_name);
  *request.mutable_camera() = camera;
  request.set_num_keypoints(static_cast<uint32_t>(keypoints_xy.size() / 2));
  request.set_keypoints(keypoints_xy.data(), keypoints_xy.size() * sizeof(float));
  request.set_descriptor_dim(descriptor_dim);
  if (float16) {
    std::string packed(descriptors.size() * 2, '\0');
    for (size_t i = 0; i < descriptors.size(); ++i) {
      const uint16_t half = ToHalf(descriptors[i]);
      std::memcpy(packed.data() + 2 * i, &half, 2);
    }
    request.set_descriptor_type(wire::DESCRIPTOR_FLOAT16);
    request.set_descriptors(std::move(packed));
  } else {
    request.set_descriptor_type(wire::DESCRIPTOR_FLOAT32);
    request.set_descriptors(descriptors.data(), descriptors.size() * sizeof(float));
  }
  return request;
}

LocalizationClient::LocalizationClient(const ClientOptions& options)
    : options_(options), state_(std::make_unique<State>()) {
  if (options_.timeout_ms <= 0 || options_.retries < 0) {
    throw std::invalid_argument(fmt::format("client: timeout_ms {} and retries {} must be positive",
                                            options_.timeout_ms, options_.retries));
  }
  if (options_.servers.empty()) throw std::invalid_argument("client: no server given");
  for (const std::string& server : options_.servers) {
    if (server.empty()) throw std::invalid_argument("client: an empty server endpoint");
  }
  if (!options_.curve_secret_key.empty() && options_.curve_public_key.empty()) {
    char public_key[41];
    if (zmq_curve_public(public_key, options_.curve_secret_key.c_str()) != 0) {
      throw std::invalid_argument("client: the CURVE secret key is no Z85 key");
    }
    options_.curve_public_key = public_key;
  }
  if (!options_.curve_server_key.empty() && options_.curve_public_key.empty()) {
    char public_key[41];
    char secret_key[41];
    if (zmq_curve_keypair(public_key, secret_key) != 0) {
      throw std::invalid_argument("client: libzmq lacks CURVE support");
    }
    options_.curve_public_key = public_key;
    options_.curve_secret_key = secret_key;
  }
  Connect();
}

LocalizationClient::~LocalizationClient() = default;

void LocalizationClient::Connect() {
  const std::string& server = options_.servers[current_];
  // The old socket stops reporting before its monitor closes. libzmq's I/O thread sends each
  // event with a blocking send: one sent to a closed monitor (the old socket retrying a dead
  // server) would stall it, and with it every later socket of this client, which then times out
  // on live servers.
  if (state_->socket) zmq_socket_monitor(state_->socket.handle(), nullptr, 0);
  state_->socket.close();
  state_->monitor.close();
  state_->socket = zmq::socket_t(state_->context, zmq::socket_type::dealer);
  // A closed attempt's unsent request is dropped rather than delaying the exit.
  state_->socket.set(zmq::sockopt::linger, 0);
  if (!options_.curve_server_key.empty()) {
    state_->socket.set(zmq::sockopt::curve_serverkey, options_.curve_server_key);
    state_->socket.set(zmq::sockopt::curve_publickey, options_.curve_public_key);
    state_->socket.set(zmq::sockopt::curve_secretkey, options_.curve_secret_key);
  }
  const std::string monitor_endpoint = fmt::format("inproc://hscloc-client-monitor-{}-{}",
                                                   static_cast<void*>(this), ++state_->generation);
  if (zmq_socket_monitor(state_->socket.handle(), monitor_endpoint.c_str(),
                         ZMQ_EVENT_CONNECTED | ZMQ_EVENT_DISCONNECTED | ZMQ_EVENT_CONNECT_RETRIED |
                             ZMQ_EVENT_HANDSHAKE_SUCCEEDED) != 0) {
    throw std::runtime_error("client: cannot monitor the connection");
  }
  state_->monitor = zmq::socket_t(state_->context, zmq::socket_type::pair);
  state_->monitor.connect(monitor_endpoint);
  state_->connected = false;
  state_->handshaken = false;
  try {
    state_->socket.connect(server);
  } catch (const zmq::error_t& error) {
    throw std::invalid_argument(
        fmt::format("client: cannot connect to '{}': {}", server, error.what()));
  }
}

void LocalizationClient::FailOver() {
  current_ = (current_ + 1) % options_.servers.size();
  Connect();
}

LocalizationClient::Attempt LocalizationClient::Send(const std::string& payload,
                                                     std::chrono::milliseconds timeout,
                                                     wire::Response& reply) {
  // The call id travels as an envelope frame that the server echoes, so a late reply to an
  // abandoned attempt is recognised and dropped.
  const std::string call_id = std::to_string(++next_call_);
  state_->socket.send(zmq::buffer(call_id), zmq::send_flags::sndmore);
  state_->socket.send(zmq::buffer(payload), zmq::send_flags::none);
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (true) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0) return Attempt::kTimedOut;
    zmq::pollitem_t items[] = {{state_->socket.handle(), 0, ZMQ_POLLIN, 0},
                               {state_->monitor.handle(), 0, ZMQ_POLLIN, 0}};
    zmq::poll(items, 2, left);
    if (items[1].revents & ZMQ_POLLIN) {
      std::vector<zmq::message_t> event;
      if (zmq::recv_multipart(state_->monitor, std::back_inserter(event)) && !event.empty() &&
          event[0].size() >= sizeof(uint16_t)) {
        uint16_t kind = 0;
        std::memcpy(&kind, event[0].data(), sizeof(kind));
        state_->connected = state_->connected || kind == ZMQ_EVENT_CONNECTED;
        state_->handshaken = state_->handshaken || kind == ZMQ_EVENT_HANDSHAKE_SUCCEEDED;
        // A dropped connection loses the request; a refused one never carried it.
        if (kind == ZMQ_EVENT_DISCONNECTED && state_->handshaken) return Attempt::kConnectionLost;
        if (kind == ZMQ_EVENT_CONNECT_RETRIED && !state_->connected) return Attempt::kRefused;
      }
    }
    if (!(items[0].revents & ZMQ_POLLIN)) continue;
    std::vector<zmq::message_t> frames;
    if (!zmq::recv_multipart(state_->socket, std::back_inserter(frames)) || frames.size() != 2 ||
        frames[0].to_string() != call_id) {
      continue;
    }
    if (!reply.ParseFromArray(frames[1].data(), static_cast<int>(frames[1].size()))) {
      throw ClientError(
          fmt::format("{}: the reply is not an hscloc Response", options_.servers[current_]));
    }
    return Attempt::kAnswered;
  }
}

wire::Response LocalizationClient::Call(wire::Request request) {
  request.set_protocol_version(kClientProtocolVersion);
  const std::string payload = request.SerializeAsString();
  const bool resendable = !request.has_reload();
  const auto timeout = std::chrono::milliseconds(options_.timeout_ms);
  const auto deadline = std::chrono::steady_clock::now() + timeout * (options_.retries + 1);
  int timeouts = 0;
  size_t failed_fast_in_a_row = 0;    // lost or refused connections, not timeouts
  std::vector<std::string> outcomes;  // per attempt, for the error message
  while (true) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    const std::string server = options_.servers[current_];
    wire::Response reply;
    const Attempt attempt = Send(payload, std::min(timeout, left), reply);
    if (attempt == Attempt::kAnswered) return reply;
    outcomes.push_back(fmt::format("{} {}", server,
                                   attempt == Attempt::kTimedOut         ? "timed out"
                                   : attempt == Attempt::kConnectionLost ? "lost the connection"
                                                                         : "refused"));
    timeouts += attempt == Attempt::kTimedOut;
    failed_fast_in_a_row = attempt == Attempt::kTimedOut ? 0 : failed_fast_in_a_row + 1;
    FailOver();  // Lazy Pirate: a fresh socket for whatever comes next
    if (!resendable) {
      throw ClientError(fmt::format(
          "{}: no reply ({}); a reload changes the server's state and is not resent: ask Health "
          "which map it serves",
          server, outcomes.back()));
    }
    if (timeouts > options_.retries || std::chrono::steady_clock::now() >= deadline) {
      throw ClientError(fmt::format("no reply within {} ms after {} attempts: {}",
                                    options_.timeout_ms * (options_.retries + 1), outcomes.size(),
                                    fmt::join(outcomes, ", ")));
    }
    ++failovers_;
    // Every server refused or dropped us: they may be restarting; wait a little before the next
    // round.
    if (failed_fast_in_a_row >= options_.servers.size()) {
      std::this_thread::sleep_for(std::min(std::chrono::milliseconds(100),
                                           std::chrono::duration_cast<std::chrono::milliseconds>(
                                               deadline - std::chrono::steady_clock::now())));
    }
  }
}

wire::LocalizeResponse LocalizationClient::Localize(const wire::LocalizeRequest& request) {
  wire::Request envelope;
  *envelope.mutable_localize() = request;
  wire::Response response = Call(std::move(envelope));
  if (!response.has_localize()) {
    wire::LocalizeResponse error;
    error.set_request_id(request.request_id());
    error.set_status(response.status() == wire::STATUS_UNSPECIFIED ? wire::INTERNAL
                                                                   : response.status());
    error.set_error_message(response.error_message());
    return error;
  }
  return response.localize();
}

wire::HealthResponse LocalizationClient::Health() {
  wire::Request request;
  request.mutable_health();
  const wire::Response response = Call(std::move(request));
  if (!response.has_health()) throw ClientError("health: " + response.error_message());
  return response.health();
}

wire::InfoResponse LocalizationClient::Info() {
  wire::Request request;
  request.mutable_info();
  const wire::Response response = Call(std::move(request));
  if (!response.has_info()) throw ClientError("info: " + response.error_message());
  return response.info();
}

wire::ReloadResponse LocalizationClient::Reload() {
  wire::Request request;
  request.mutable_reload();
  const wire::Response response = Call(std::move(request));
  if (!response.has_reload()) throw ClientError("reload: " + response.error_message());
  return response.reload();
}

}  // namespace hscloc
