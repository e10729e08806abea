// Fuzzes the rate tables' reply decoders: ACL (drivers/acl.h, each framing)
// and AERO (drivers/aero.h), and the value parsers behind them.
//
// The input picks a decoder, then is a script: each op appends raw bytes, a
// well-framed reply whose payload comes from fuzz bytes, or a chunk
// boundary. The stream is fed once whole and once in the chosen chunks.
// Checked: no crash; both feedings give the same replies up to the first
// error, and both meet that error; no payload exceeds the cap or ends in
// CR/LF; a value is only ever parsed out of a field that is a number by the
// grammar (TM-8004 §2.6.1), so nothing is emitted from a malformed frame.
#include <fuzzer/FuzzedDataProvider.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "fuzz_check.h"
#include "gyrotherm/drivers/acl.h"
#include "gyrotherm/drivers/aero.h"

using namespace gyrotherm::drivers;

namespace {

// The number grammar, written again independently of acl::parse_number.
bool is_number_text(std::string_view s) {
  while (!s.empty() &&
         (s.front() == ' ' || s.front() == '\t' || s.front() == '\r' || s.front() == '\n'))
    s.remove_prefix(1);
  while (!s.empty() &&
         (s.back() == ' ' || s.back() == '\t' || s.back() == '\r' || s.back() == '\n'))
    s.remove_suffix(1);
  if (s.empty()) return false;
  bool digit = false;
  for (char c : s) {
    if (c >= '0' && c <= '9')
      digit = true;
    else if (c != '+' && c != '-' && c != '.' && c != 'E' && c != 'e')
      return false;
  }
  return digit;
}

struct Outcome {
  std::vector<std::string> replies;  // code and payload, or the AERO text
  bool error = false;
};

std::string frame(acl::ReplyFraming framing, uint32_t code, const std::string& payload) {
  switch (framing) {
    case acl::ReplyFraming::kAscii: {
      char head[16];
      std::snprintf(head, sizeof head, "%04u%04zu", code % 10000, payload.size() % 10000);
      return head + payload;
    }
    case acl::ReplyFraming::kBinaryLe:
    case acl::ReplyFraming::kBinaryBe: {
      std::string out;
      for (uint32_t v : {code, static_cast<uint32_t>(payload.size())}) {
        for (int i = 0; i < 4; ++i) {
          const int shift = framing == acl::ReplyFraming::kBinaryLe ? 8 * i : 8 * (3 - i);
          out += static_cast<char>((v >> shift) & 0xff);
        }
      }
      return out + payload;
    }
    case acl::ReplyFraming::kLine:
      return payload + "\r\n";
  }
  return payload;
}

void check_acl_payload(const acl::Reply& r) {
  FUZZ_CHECK(r.payload.size() <= acl::kMaxPayloadBytes);
  FUZZ_CHECK(r.payload.empty() || (r.payload.back() != '\r' && r.payload.back() != '\n'));
  const auto fields = acl::split_fields(r.payload);
  if (auto s = acl::parse_state(r.payload); s.ok()) {
    FUZZ_CHECK(fields.size() == 4);
    FUZZ_CHECK(is_number_text(fields[2]) && is_number_text(fields[3]));
    FUZZ_CHECK(std::isfinite(s->rate_dps) && std::isfinite(s->position_deg));
  }
  if (auto l = acl::parse_limits(r.payload); l.ok()) {
    FUZZ_CHECK(fields.size() == 3);
    for (const auto& f : fields) FUZZ_CHECK(is_number_text(f));
    FUZZ_CHECK(l->max_rate_dps > 0 && l->max_accel_dps2 > 0);
  }
  for (const auto& f : fields) {
    if (auto v = acl::parse_number(f); v.ok()) FUZZ_CHECK(is_number_text(f) && std::isfinite(*v));
  }
}

template <class Decoder, class Emit>
Outcome run(Decoder& d, const std::string& stream, const std::vector<std::size_t>& chunks,
            Emit emit) {
  Outcome out;
  std::size_t pos = 0;
  auto drain = [&] {
    while (!out.error) {
      auto r = d.next();
      if (!r.ok()) {
        out.error = true;
        return;
      }
      if (!*r) return;
      out.replies.push_back(emit(**r));
    }
  };
  for (std::size_t c : chunks) {
    const std::size_t n = std::min(c, stream.size() - pos);
    d.feed(std::string_view(stream).substr(pos, n));
    pos += n;
    drain();
  }
  d.feed(std::string_view(stream).substr(pos));
  drain();
  return out;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  FuzzedDataProvider in(data, size);
  const int which = in.ConsumeIntegralInRange<int>(0, 4);  // 4: AERO
  const auto framing = static_cast<acl::ReplyFraming>(std::min(which, 3));
  std::string stream;
  std::vector<std::size_t> chunks;
  while (in.remaining_bytes() > 0 && stream.size() < 64 * 1024) {
    switch (in.ConsumeIntegralInRange<int>(0, 3)) {
      case 0:  // raw bytes
        stream += in.ConsumeBytesAsString(in.ConsumeIntegralInRange<std::size_t>(0, 64));
        break;
      case 1: {  // a well-framed reply
        const auto code = in.ConsumeBool() ? 0u : in.ConsumeIntegral<uint32_t>();
        const auto payload = in.ConsumeRandomLengthString(128);
        stream += which == 4 ? payload + "\r>\r" : frame(framing, code, payload);
        break;
      }
      case 2:  // a state answer, as the controller would send it
        stream += which == 4
                      ? std::to_string(in.ConsumeIntegral<int16_t>()) + "\r>\r"
                      : frame(framing, 0,
                              "Rate;Closed;" + std::to_string(in.ConsumeFloatingPoint<double>()) +
                                  ";" + std::to_string(in.ConsumeIntegral<int16_t>()));
        break;
      case 3:
        chunks.push_back(in.ConsumeIntegralInRange<std::size_t>(0, 80));
        break;
    }
  }

  Outcome whole, split;
  if (which == 4) {
    auto emit = [](const std::string& reply) {
      if (auto v = aero::parse_number(reply); v.ok())
        FUZZ_CHECK(is_number_text(reply) && std::isfinite(*v));
      if (auto s = aero::parse_status(reply); s.ok()) FUZZ_CHECK(is_number_text(reply));
      FUZZ_CHECK(reply.size() <= aero::kMaxLineBytes + 1);
      return reply;
    };
    aero::ReplyDecoder a, b;
    whole = run(a, stream, {}, emit);
    split = run(b, stream, chunks, emit);
  } else {
    auto emit = [](const acl::Reply& r) {
      check_acl_payload(r);
      return std::to_string(r.code) + ":" + r.payload;
    };
    acl::ReplyDecoder a(framing), b(framing);
    whole = run(a, stream, {}, emit);
    split = run(b, stream, chunks, emit);
  }
  // The chunking does not matter: the same replies, and the same error
  // after them.
  FUZZ_CHECK(whole.error == split.error);
  FUZZ_CHECK(whole.replies == split.replies);
  return 0;
}
