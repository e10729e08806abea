// Result<T> and Status: expected failures as values.
//
// Device timeouts, bad configuration, bad requests are not exceptional in a
// station that runs for weeks; they come back as an Error carrying a message a
// technician can act on and whether retrying may help (transient) or not
// (permanent). Exceptions from libraries are caught at thread and handler
// boundaries and turned into these.
#pragma once

#include <cassert>
#include <string>
#include <utility>
#include <variant>

namespace gyrotherm {

struct Error {
  std::string message;
  // True when the same operation may succeed later (timeout, disconnect,
  // device busy); false when retrying cannot help (bad config, bad input).
  bool transient = false;

  static Error Transient(std::string msg) { return Error{std::move(msg), true}; }
  static Error Permanent(std::string msg) { return Error{std::move(msg), false}; }
};

template <class T>
class [[nodiscard]] Result {
 public:
  Result(T value) : v_(std::move(value)) {}      // NOLINT(google-explicit-constructor)
  Result(Error error) : v_(std::move(error)) {}  // NOLINT(google-explicit-constructor)

  bool ok() const { return v_.index() == 0; }
  explicit operator bool() const { return ok(); }

  const T& value() const& {
    assert(ok());
    return std::get<0>(v_);
  }
  T& value() & {
    assert(ok());
    return std::get<0>(v_);
  }
  T&& value() && {
    assert(ok());
    return std::get<0>(std::move(v_));
  }
  const T& operator*() const& { return value(); }
  T& operator*() & { return value(); }
  const T* operator->() const { return &value(); }
  T* operator->() { return &value(); }

  const Error& error() const {
    assert(!ok());
    return std::get<1>(v_);
  }

 private:
  std::variant<T, Error> v_;
};

// Result of an operation that yields nothing but may fail.
class [[nodiscard]] Status {
 public:
  Status() = default;
  Status(Error error) : error_(std::move(error)), ok_(false) {}  // NOLINT

  static Status Ok() { return Status(); }
  bool ok() const { return ok_; }
  explicit operator bool() const { return ok_; }
  const Error& error() const {
    assert(!ok_);
    return error_;
  }

 private:
  Error error_;
  bool ok_ = true;
};

}  // namespace gyrotherm
