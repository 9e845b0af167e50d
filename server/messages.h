// The replies every hscloc socket sends (envelopes with the protocol and server version, errors
// that carry their status), the moving of multipart messages between sockets, and binding.
#pragma once

#include <string>
#include <vector>
#include <zmq.hpp>

#include "proto/hscloc.pb.h"

namespace hscloc {

// A response with the protocol version and the server's release set.
wire::Response EnvelopeResponse();
// A response whose envelope carries `status` and `message`.
wire::Response ErrorResponse(wire::Status status, const std::string& message);
// A response to `request` carrying `status` in the envelope and, for a Localize request, in the
// localize message too (with its request id), so that clients looking at either see it.
wire::Response RefusalFor(const wire::Request& request, wire::Status status,
                          const std::string& message);

// Sends `frames` as one multipart message (the frames are consumed); false when the socket took
// none of it (a non-blocking send with nowhere to queue).
bool SendFrames(zmq::socket_t& socket, std::vector<zmq::message_t>& frames);
void SendFrames(zmq::socket_t& socket, const std::vector<std::string>& frames);
// Envelope frames, then `payload`.
void SendReply(zmq::socket_t& socket, const std::vector<zmq::message_t>& envelope,
               const wire::Response& response);
// Binds `socket` to `endpoint`; throws std::invalid_argument naming the endpoint and the command
// line `flag` that gave it.
void BindOrThrow(zmq::socket_t& socket, const std::string& endpoint, const std::string& flag);
// One multipart message as strings; empty when none could be read.
std::vector<std::string> ReceiveFrames(zmq::socket_t& socket);

}  // namespace hscloc
