#include "server/messages.h"

#include <zmq_addon.hpp>

#include "server/wire.h"
#include "util/check.h"

namespace hscloc {

wire::Response EnvelopeResponse() {
  wire::Response response;
  response.set_protocol_version(kProtocolVersion);
  response.set_server_version(kServerVersion);
  return response;
}

wire::Response ErrorResponse(wire::Status status, const std::string& message) {
  wire::Response response = EnvelopeResponse();
  response.set_status(status);
  response.set_error_message(message);
  return response;
}

wire::Response RefusalFor(const wire::Request& request, wire::Status status,
                          const std::string& message) {
  wire::Response response = ErrorResponse(status, message);
  if (request.has_localize()) {
    wire::LocalizeResponse* localize = response.mutable_localize();
    localize->set_request_id(request.localize().request_id());
    localize->set_status(status);
    localize->set_error_message(message);
  } else if (request.has_reload()) {
    response.mutable_reload()->set_status(status);
    response.mutable_reload()->set_error_message(message);
  }
  return response;
}

bool SendFrames(zmq::socket_t& socket, std::vector<zmq::message_t>& frames) {
  bool sent = true;
  for (size_t i = 0; i < frames.size(); ++i) {
    sent = socket
               .send(frames[i],
                     i + 1 < frames.size() ? zmq::send_flags::sndmore : zmq::send_flags::none)
               .has_value() &&
           sent;
  }
  return sent;
}

void SendFrames(zmq::socket_t& socket, const std::vector<std::string>& frames) {
  for (size_t i = 0; i < frames.size(); ++i) {
    socket.send(zmq::buffer(frames[i]),
                i + 1 < frames.size() ? zmq::send_flags::sndmore : zmq::send_flags::none);
  }
}

void SendReply(zmq::socket_t& socket, const std::vector<zmq::message_t>& envelope,
               const wire::Response& response) {
  for (const zmq::message_t& frame : envelope) {
    socket.send(zmq::message_t(frame.data(), frame.size()), zmq::send_flags::sndmore);
  }
  const std::string payload = response.SerializeAsString();
  socket.send(zmq::message_t(payload.data(), payload.size()), zmq::send_flags::none);
}

void BindOrThrow(zmq::socket_t& socket, const std::string& endpoint, const std::string& flag) {
  try {
    socket.bind(endpoint);
  } catch (const zmq::error_t& error) {
    ThrowInvalidArgument("cannot bind {} ({}): {}", endpoint, flag, error.what());
  }
}

std::vector<std::string> ReceiveFrames(zmq::socket_t& socket) {
  std::vector<zmq::message_t> messages;
  std::vector<std::string> frames;
  if (!zmq::recv_multipart(socket, std::back_inserter(messages))) return frames;
  for (const zmq::message_t& message : messages) frames.push_back(message.to_string());
  return frames;
}

}  // namespace hscloc
