// PeerEnd: the controller's end of a test peer's byte link, so that one
// peer (acl_peer.h, aero_peer.h) serves either transport the drivers'
// ByteLink has (byte_link.h):
//   kTcp  a listening socket on 127.0.0.1, port chosen by the system; one
//         client at a time, a new connection replaces the old one (as a
//         controller's single Ethernet session, or a serial device server
//         in TCP server mode);
//   kPty  the master of a pseudo-terminal (drivers::Pty): device() is the
//         slave path a driver opens as its serial line.
//
// receive() belongs to the peer's own thread; send(), the accessors and
// hang_up() may be called from any thread.
#pragma once

#include <atomic>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>

#include "gyrotherm/drivers/pty.h"

namespace gyrotherm::testing {

class PeerEnd {
 public:
  enum class Transport { kTcp, kPty };

  // Throws std::runtime_error when it cannot listen or open a pty.
  explicit PeerEnd(Transport transport);
  ~PeerEnd();
  PeerEnd(const PeerEnd&) = delete;
  PeerEnd& operator=(const PeerEnd&) = delete;

  Transport transport() const { return transport_; }
  int port() const { return port_; }  // kTcp; 0 for kPty
  std::string device() const;         // kPty; "" for kTcp
  // kTcp: connections accepted so far; kPty: 1 (the line is one session).
  int connections() const;

  struct Received {
    std::string bytes;
    // A new client was accepted (kTcp): what came before belonged to
    // another session.
    bool new_connection = false;
  };
  // Waits up to `timeout_ms` for something to happen and returns it (empty
  // on time-out, or when the client left).
  Received receive(int timeout_ms);
  // To the current client; dropped when there is none.
  void send(std::string_view bytes);
  // kTcp: ends the client's connection (the driver reads its end; the
  // next connection is accepted as usual). kPty: nothing (drivers::Pty's
  // close_master() is the hang-up of a serial line; see aero_test.cpp).
  void hang_up();

 private:
  Transport transport_;
  int listen_fd_ = -1;
  int port_ = 0;
  std::optional<drivers::Pty> pty_;
  std::atomic<int> connections_{0};
  mutable std::mutex mu_;  // client_fd_ changes, sends
  int client_fd_ = -1;
};

}  // namespace gyrotherm::testing
