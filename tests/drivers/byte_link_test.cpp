// The byte links under the rate-table protocols (byte_link.h): the
// transport a [table] connection names, the links make_table_link refuses,
// TcpLink against a real loopback listener and SerialLink on a real pty.
#include "gyrotherm/drivers/byte_link.h"

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cstdint>
#include <span>
#include <string>

#include "gyrotherm/drivers/pty.h"
#include "peer_end.h"
#include "test_time.h"

namespace gyrotherm::drivers {
namespace {

using namespace std::chrono_literals;
using Steady = std::chrono::steady_clock;
using testing::PeerEnd;

Status write_master(Pty& pty, std::string_view bytes) {
  return pty.write_master(std::span(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size()));
}

TEST(TableTransport, TheProfilesDefaultUnlessNamed) {
  TableConnection c;
  c.profile = "acutrol";
  EXPECT_EQ(table_transport(c), "tcp");  // TM-9384C: the controller's Ethernet port
  c.profile = "aero";
  EXPECT_EQ(table_transport(c), "serial");
  c.transport = "tcp";
  EXPECT_EQ(table_transport(c), "tcp");
  c.profile = "acutrol";
  c.transport = "serial";
  EXPECT_EQ(table_transport(c), "serial");
}

TEST(MakeTableLink, EachTransportGetsItsLink) {
  TableConnection c;
  c.host = "127.0.0.1";
  c.port = 9878;
  auto tcp = make_table_link(c, "turntable");
  ASSERT_TRUE(tcp.ok()) << tcp.error().message;
  EXPECT_NE(dynamic_cast<TcpLink*>(tcp->get()), nullptr);
  EXPECT_EQ((*tcp)->description(), "127.0.0.1:9878");
  EXPECT_FALSE((*tcp)->is_open());

  c.profile = "aero";
  c.device = "/dev/ttyUSB2";
  auto serial = make_table_link(c, "turntable");
  ASSERT_TRUE(serial.ok()) << serial.error().message;
  EXPECT_NE(dynamic_cast<SerialLink*>(serial->get()), nullptr);
  EXPECT_EQ((*serial)->description(), "/dev/ttyUSB2");
}

TEST(MakeTableLink, RefusesWhatCannotWorkNamingIt) {
  const auto refused = [](TableConnection c) {
    auto link = make_table_link(c, "turntable");
    if (link.ok()) return std::string("(made)");
    EXPECT_FALSE(link.error().transient) << link.error().message;
    return link.error().message;
  };
  TableConnection c;
  c.transport = "serial";  // acutrol, no device
  EXPECT_EQ(refused(c), "turntable: transport serial: no serial device given");
  c.device = "/dev/ttyS0";
  c.baud = 0;
  EXPECT_EQ(refused(c), "turntable: baud 0 (must be positive)");
  c = TableConnection{};
  c.profile = "aero";
  c.transport = "tcp";
  c.port = 70000;
  EXPECT_EQ(refused(c), "turntable: port 70000 is not a TCP port");
  c.port = 4001;
  c.host = "";
  EXPECT_EQ(refused(c), "turntable: transport tcp: no host given");
  c.transport = "usb";
  EXPECT_EQ(refused(c), "turntable: transport \"usb\" is none of tcp, serial");
}

TEST(TcpLink, ReadsWhatComesWaitsOutItsDeadlineAndReportsTheEnd) {
  PeerEnd peer(PeerEnd::Transport::kTcp);
  TcpLink link(TcpLinkOptions{"127.0.0.1", peer.port()});
  ASSERT_TRUE(link.open(Steady::now() + 2s).ok());
  ASSERT_TRUE(link.is_open());
  ASSERT_TRUE(link.write_all("*IDN?\r\n", Steady::now() + 2s).ok());
  std::string got;
  ASSERT_TRUE(testing::wait_for_condition(
      [&] {
        got += peer.receive(10).bytes;
        return got == "*IDN?\r\n";
      },
      2000ms))
      << got;

  std::string into = "kept";
  const auto t0 = Steady::now();
  auto n = link.read_some(into, t0 + 100ms);
  ASSERT_TRUE(n.ok()) << n.error().message;
  EXPECT_EQ(*n, 0u);
  EXPECT_GE(Steady::now() - t0, 100ms) << "returned before its deadline";
  EXPECT_EQ(into, "kept");

  peer.send("0000");
  ASSERT_TRUE(testing::wait_for_condition(
      [&] {
        n = link.read_some(into, Steady::now() + 50ms);
        return !n.ok() || into == "kept0000";
      },
      2000ms))
      << into;
  ASSERT_TRUE(n.ok()) << n.error().message;

  peer.hang_up();
  ASSERT_TRUE(testing::wait_for_condition(
      [&] {
        auto r = link.read_some(into, Steady::now() + 50ms);
        return !r.ok() && r.error().message == "connection closed by the controller" &&
               r.error().transient;
      },
      2000ms));
  link.close();
  EXPECT_FALSE(link.is_open());
}

TEST(TcpLink, NobodyListeningIsTransient) {
  int port = 0;
  {
    PeerEnd gone(PeerEnd::Transport::kTcp);
    port = gone.port();
  }
  TcpLink link(TcpLinkOptions{"127.0.0.1", port});
  const Status st = link.open(Steady::now() + 1s);
  ASSERT_FALSE(st.ok());
  EXPECT_TRUE(st.error().transient);
  EXPECT_EQ(st.error().message.rfind("cannot connect: ", 0), 0u) << st.error().message;
  EXPECT_FALSE(link.is_open());
}

// A serial line keeps what arrived while nobody read it (a reply to a
// request of the session before a reconnect): opening drops it, so the next
// exchange starts clean as a new TCP connection does.
TEST(SerialLink, OpeningDiscardsWhatTheLineHeldBefore) {
  auto pty = Pty::open(/*nonblocking_master=*/true);
  ASSERT_TRUE(pty.ok()) << pty.error().message;
  ASSERT_TRUE(write_master(*pty, "00000002OK").ok());
  SerialLink link(SerialOptions{pty->slave_path(), 9600, Parity::kNone});
  EXPECT_EQ(link.description(), pty->slave_path());
  ASSERT_TRUE(link.open(Steady::now() + 1s).ok());
  std::string into;
  auto n = link.read_some(into, Steady::now() + 100ms);
  ASSERT_TRUE(n.ok()) << n.error().message;
  EXPECT_EQ(*n, 0u) << "stale bytes read: " << into;

  ASSERT_TRUE(write_master(*pty, ">").ok());
  n = link.read_some(into, Steady::now() + 2s);
  ASSERT_TRUE(n.ok()) << n.error().message;
  EXPECT_EQ(into, ">");

  ASSERT_TRUE(link.write_all("STA\r\n", Steady::now() + 1s).ok());
  std::string sent;
  ASSERT_TRUE(testing::wait_for_condition(
      [&] {
        char buf[64];
        const ssize_t r = ::read(pty->master_fd(), buf, sizeof buf);
        if (r > 0) sent.append(buf, static_cast<std::size_t>(r));
        return sent == "STA\r\n";
      },
      2000ms))
      << sent;

  pty->close_master();  // a hang-up: transient, without the device repeated
  auto hung = link.read_some(into, Steady::now() + 1s);
  ASSERT_FALSE(hung.ok());
  EXPECT_TRUE(hung.error().transient);
  EXPECT_EQ(hung.error().message.rfind("hang-up", 0), 0u) << hung.error().message;
}

TEST(SerialLink, AMissingDeviceIsTransientAndNamedOnce) {
  SerialLink link(SerialOptions{"/nonexistent/ttyGT0", 9600, Parity::kNone});
  const Status st = link.open(Steady::now() + 1s);
  ASSERT_FALSE(st.ok());
  EXPECT_TRUE(st.error().transient);
  EXPECT_EQ(st.error().message.find("/nonexistent/ttyGT0"), std::string::npos)
      << "the table names the device: " << st.error().message;
  EXPECT_FALSE(link.is_open());
}

}  // namespace
}  // namespace gyrotherm::drivers
