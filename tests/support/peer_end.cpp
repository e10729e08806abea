#include "peer_end.h"

#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cstdint>
#include <span>
#include <stdexcept>

namespace gyrotherm::testing {

PeerEnd::PeerEnd(Transport transport) : transport_(transport) {
  if (transport_ == Transport::kPty) {
    auto pty = drivers::Pty::open(/*nonblocking_master=*/true);
    if (!pty.ok()) throw std::runtime_error("PeerEnd: " + pty.error().message);
    pty_.emplace(std::move(pty).value());
    connections_ = 1;
    return;
  }
  listen_fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  a.sin_port = 0;
  if (listen_fd_ < 0 || ::bind(listen_fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 ||
      ::listen(listen_fd_, 4) != 0) {
    if (listen_fd_ >= 0) ::close(listen_fd_);
    throw std::runtime_error("PeerEnd: cannot listen on 127.0.0.1");
  }
  socklen_t len = sizeof a;
  ::getsockname(listen_fd_, reinterpret_cast<sockaddr*>(&a), &len);
  port_ = ntohs(a.sin_port);
}

PeerEnd::~PeerEnd() {
  if (client_fd_ >= 0) ::close(client_fd_);
  if (listen_fd_ >= 0) ::close(listen_fd_);
}

std::string PeerEnd::device() const { return pty_ ? pty_->slave_path() : std::string(); }

int PeerEnd::connections() const { return connections_.load(); }

PeerEnd::Received PeerEnd::receive(int timeout_ms) {
  Received out;
  char buf[512];
  if (transport_ == Transport::kPty) {
    pollfd p{pty_->master_fd(), POLLIN, 0};
    if (::poll(&p, 1, timeout_ms) <= 0) return out;
    const ssize_t n = ::read(pty_->master_fd(), buf, sizeof buf);
    if (n > 0) out.bytes.assign(buf, static_cast<std::size_t>(n));
    return out;
  }
  // Only this thread changes client_fd_: reading it unlocked here is safe.
  pollfd fds[2] = {{listen_fd_, POLLIN, 0}, {client_fd_, POLLIN, 0}};
  if (::poll(fds, client_fd_ >= 0 ? 2 : 1, timeout_ms) <= 0) return out;
  if (fds[0].revents & POLLIN) {
    const int fd = ::accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC);
    if (fd >= 0) {
      std::lock_guard lock(mu_);
      if (client_fd_ >= 0) ::close(client_fd_);
      client_fd_ = fd;
      ++connections_;
      out.new_connection = true;
    }
    return out;
  }
  if (client_fd_ < 0 || !(fds[1].revents & (POLLIN | POLLHUP | POLLERR))) return out;
  const ssize_t n = ::recv(client_fd_, buf, sizeof buf, 0);
  if (n <= 0) {
    std::lock_guard lock(mu_);
    ::close(client_fd_);
    client_fd_ = -1;
    return out;
  }
  out.bytes.assign(buf, static_cast<std::size_t>(n));
  return out;
}

void PeerEnd::send(std::string_view bytes) {
  std::lock_guard lock(mu_);
  if (transport_ == Transport::kPty) {
    (void)pty_->write_master(
        std::span(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size()));
    return;
  }
  if (client_fd_ >= 0) ::send(client_fd_, bytes.data(), bytes.size(), MSG_NOSIGNAL);
}

void PeerEnd::hang_up() {
  // shutdown, not close: the descriptor stays the peer thread's to close
  // (when it reads the end), so no other thread's new descriptor can take
  // its number meanwhile.
  std::lock_guard lock(mu_);
  if (client_fd_ >= 0) ::shutdown(client_fd_, SHUT_RDWR);
}

}  // namespace gyrotherm::testing
