// ByteLink: the bytes under a rate-table protocol, apart from the protocol.
// AcutrolTable (ACL) and AeroTable (AERO mnemonics) talk through one, so
// either protocol runs over either transport ([table] transport,
// docs/table.md "Transport"):
//   TcpLink     a TCP connection: the ACUTROL3000's Ethernet port
//               (TM-9384C), or a serial device server (an RS-232-to-
//               Ethernet box in TCP server mode) in front of an AERO
//               controller's serial port;
//   SerialLink  a serial line, 8N1, through SerialPort: an AERO
//               controller's RS-232 port, or ACL on RS-232 (TM-9411: the
//               box that carries it to the ACUTROL's Ethernet port).
//
// A link knows nothing of requests, replies, timeouts per request or
// reconnecting: the tables frame and time their exchanges, decide what a
// failure means and when to reopen (LinkHealth's backoff). Errors here are
// short ("cannot connect: Connection refused", "hang-up (POLLHUP)"): the
// tables prefix their name and description(). Not thread-safe: the tables
// hold their mutex around every call.
#pragma once

#include <chrono>
#include <cstddef>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include "gyrotherm/core/result.h"
#include "gyrotherm/drivers/rate_table.h"
#include "gyrotherm/drivers/serial_port.h"

namespace gyrotherm::drivers {

class ByteLink {
 public:
  using Deadline = std::chrono::steady_clock::time_point;

  virtual ~ByteLink() = default;

  // Connects / opens the line, giving up at `deadline`. A link already open
  // is closed first. Transient error: may work later (refused, unreachable,
  // a device missing or held by another process); permanent: will not
  // (no permission, an unsupported baud rate).
  virtual Status open(Deadline deadline) = 0;
  virtual void close() = 0;
  virtual bool is_open() const = 0;
  // Sends all of `bytes` by `deadline`. Any error is transient and leaves
  // the link to be closed by the caller.
  virtual Status write_all(std::string_view bytes, Deadline deadline) = 0;
  // Waits until `deadline` for bytes and appends what has arrived (one
  // read) to `into`: how many; 0 only when none came by the deadline. An
  // error (the other end closed or hung up) is transient.
  virtual Result<std::size_t> read_some(std::string& into, Deadline deadline) = 0;
  // Where it goes, for messages: "192.168.53.1:9878", "/dev/ttyUSB2".
  virtual const std::string& description() const = 0;
};

struct TcpLinkOptions {
  std::string host;
  int port = 0;
};

// TCP to host:port, with TCP_NODELAY (one short request at a time: no
// waiting for Nagle). Every address the host resolves to is tried in turn
// until the deadline.
class TcpLink final : public ByteLink {
 public:
  explicit TcpLink(TcpLinkOptions options);
  ~TcpLink() override;
  TcpLink(const TcpLink&) = delete;
  TcpLink& operator=(const TcpLink&) = delete;

  Status open(Deadline deadline) override;
  void close() override;
  bool is_open() const override { return fd_ >= 0; }
  Status write_all(std::string_view bytes, Deadline deadline) override;
  Result<std::size_t> read_some(std::string& into, Deadline deadline) override;
  const std::string& description() const override { return description_; }

 private:
  TcpLinkOptions options_;
  std::string description_;
  int fd_ = -1;
};

// A serial line, raw 8N1 (SerialOptions' parity: none for both table
// families), held exclusively as SerialPort does. Opening discards whatever
// the line had buffered: a reply still in flight from before a reconnect
// would otherwise be read as the answer to the next request (TCP starts
// each connection clean; a serial line does not).
class SerialLink final : public ByteLink {
 public:
  explicit SerialLink(SerialOptions options);
  ~SerialLink() override;

  Status open(Deadline deadline) override;
  void close() override;
  bool is_open() const override { return port_.has_value(); }
  Status write_all(std::string_view bytes, Deadline deadline) override;
  Result<std::size_t> read_some(std::string& into, Deadline deadline) override;
  const std::string& description() const override { return options_.device; }

 private:
  SerialOptions options_;
  std::optional<SerialPort> port_;
};

// The link `connection` names: TcpLink to host:port, or SerialLink on
// device at baud, 8N1. A permanent error, naming `name` and the key, when
// the connection cannot make one (an unknown transport, a port out of
// range, no device, a baud rate not positive); the table reports it at
// every call.
Result<std::unique_ptr<ByteLink>> make_table_link(const TableConnection& connection,
                                                  std::string_view name);

}  // namespace gyrotherm::drivers
