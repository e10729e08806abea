// The ACL codec (acl.h) against transcripts from the public sources: the
// ACUTROL3000 command language manual TM-8004 (section cited at each test),
// IEAv-EFO/acutrol3000 `acutrol3000.py` and AcutronicRobotics/acutrol
// (`acutrol.py`, `ac117.json`). Every framing, split reads and garbage.
#include "gyrotherm/drivers/acl.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <string>
#include <vector>

namespace gyrotherm::drivers::acl {
namespace {

std::string ascii_frame(unsigned code, const std::string& payload) {
  char head[16];
  std::snprintf(head, sizeof head, "%04u%04zu", code, payload.size());
  return head + payload;
}

std::string binary_frame(uint32_t code, const std::string& payload, bool little_endian) {
  std::string out;
  auto put = [&](uint32_t v) {
    for (int i = 0; i < 4; ++i) {
      const int shift = little_endian ? 8 * i : 8 * (3 - i);
      out += static_cast<char>((v >> shift) & 0xff);
    }
  };
  put(code);
  put(static_cast<uint32_t>(payload.size()));
  return out + payload;
}

// Feeds `bytes` in pieces of `chunk` and collects every reply; fails the
// test on a decoder error.
std::vector<Reply> decode_all(ReplyFraming framing, const std::string& bytes, std::size_t chunk) {
  ReplyDecoder d(framing);
  std::vector<Reply> out;
  for (std::size_t i = 0; i < bytes.size(); i += chunk) {
    d.feed(std::string_view(bytes).substr(i, chunk));
    for (;;) {
      auto r = d.next();
      EXPECT_TRUE(r.ok()) << r.error().message;
      if (!r.ok() || !*r) break;
      out.push_back(**r);
    }
  }
  return out;
}

// ---------------------------------------------------------------- commands

// TM-8004 §2.1: `:Demand:Position 3,10.5`, `:Dem:Pos 3,10.50000` and
// `:D:P 3,10.5` are the same command; we send the short form, with 10.50000
// written as 10.5.
TEST(AclCommands, ShortFormsOfTheManual) {
  EXPECT_EQ(format_number(10.50000), "10.5");
  EXPECT_EQ(demand_position(3, 10.5), ":D:P 3,10.5;:M:P 3");
  EXPECT_EQ(demand_rate(1, 10.5), ":D:R 1,10.5;:M:R 1");
  EXPECT_EQ(command_line(demand_rate(1, 10.5)), ":D:R 1,10.5;:M:R 1\r\n");  // as acutrol.py
  EXPECT_EQ(mode_off(2), ":M:O 2");
  EXPECT_EQ(interlock_close(1), ":I:C 1");
  EXPECT_EQ(interlock_open(1), ":I:O 1");
  EXPECT_EQ(interlock_reset(), ":I:R");
  EXPECT_EQ(take_remote(), ":U:L ON");  // §4.14.2 example
  EXPECT_EQ(state_query(1), ":M? 1;:I? 1;:R:R? 1;:R:P? 1");
  EXPECT_EQ(limits_query(4), ":L:R? R,4;:L:A? R,4;:L:V? R,4");
  EXPECT_EQ(error_text_query(12), ":Q:E? 12");
}

TEST(AclCommands, NumbersAreFixedPointWithoutTrailingZeros) {
  EXPECT_EQ(format_number(-3), "-3");
  EXPECT_EQ(format_number(0.000125), "0.000125");
  EXPECT_EQ(format_number(-0.0), "0");
  EXPECT_EQ(format_number(-1e-9), "0");  // below the 6 decimals sent
  EXPECT_EQ(format_number(1000), "1000");
  EXPECT_EQ(format_number(-199.999), "-199.999");
}

// ---------------------------------------------------------------- values

// TM-8004 §2.6.1.4 / §2.6.1.5 examples (the controller sends no '+', but the
// grammar allows it).
TEST(AclValues, Nr2AndNr3NumbersOfTheManual) {
  struct Case {
    const char* text;
    double value;
  } cases[] = {{"12.3", 12.3},
               {"+1.234", 1.234},
               {"-0.1234", -0.1234},
               {"1.23E+45", 1.23e45},
               {"+12.345E-67", 12.345e-67},
               {"-0.012E+3", -12.0},
               {"1", 1.0},
               {"-12", -12.0},
               {"10.", 10.0}};
  for (const auto& c : cases) {
    auto v = parse_number(c.text);
    ASSERT_TRUE(v.ok()) << c.text << ": " << v.error().message;
    EXPECT_DOUBLE_EQ(*v, c.value) << c.text;
  }
}

TEST(AclValues, RefusesWhatIsNotANumber) {
  for (const char* bad : {"", ".", "-", "1e", "1E+", "1.2.3", "1,5", "inf", "nan", "0x10", "1 2",
                          "E5", "#14abcd", "12a", "1e999"}) {
    auto v = parse_number(bad);
    EXPECT_FALSE(v.ok()) << "\"" << bad << "\" parsed as " << (v.ok() ? *v : 0);
  }
}

// TM-8004 §4.6.2: `:LIM:ACC? P,1` answers `1500.0`; the chained
// `:LIM:H P,4,...;L ...;R ...;A ...` answers `180.0;-180.0;100.0;2000.0`.
TEST(AclValues, LimitAnswersOfTheManual) {
  auto one = parse_number("1500.0");
  ASSERT_TRUE(one.ok());
  EXPECT_DOUBLE_EQ(*one, 1500.0);
  const auto fields = split_fields("180.0;-180.0;100.0;2000.0");
  ASSERT_EQ(fields.size(), 4u);
  const double expected[] = {180.0, -180.0, 100.0, 2000.0};
  for (std::size_t i = 0; i < 4; ++i) {
    auto v = parse_number(fields[i]);
    ASSERT_TRUE(v.ok());
    EXPECT_DOUBLE_EQ(*v, expected[i]);
  }
  auto limits = parse_limits("100.0;2000.0;110.0");
  ASSERT_TRUE(limits.ok()) << limits.error().message;
  EXPECT_DOUBLE_EQ(limits->max_rate_dps, 100.0);
  EXPECT_DOUBLE_EQ(limits->max_accel_dps2, 2000.0);
  ASSERT_TRUE(limits->trip_rate_dps.has_value());
  EXPECT_DOUBLE_EQ(*limits->trip_rate_dps, 110.0);
  EXPECT_FALSE(parse_limits("180.0;-180.0;100.0;2000.0").ok());  // four fields, not three
  EXPECT_FALSE(parse_limits("100.0;0.0;110.0").ok());            // a zero limit
}

// TM-8004 §4.10.1: `:R:A 2;R 2;P 2` answers acceleration;rate;position, one
// field per query; the binary form `#14<4 bytes>` is refused as a number.
TEST(AclValues, ChainedReadAnswersOneFieldPerQuery) {
  const auto fields = split_fields("0.5;-20.25;359.9\r\n");
  ASSERT_EQ(fields.size(), 3u);
  EXPECT_DOUBLE_EQ(*parse_number(fields[1]), -20.25);
  EXPECT_DOUBLE_EQ(*parse_number(fields[2]), 359.9);
  EXPECT_FALSE(parse_number("#14\x01\x02\x03\x04").ok());
}

// TM-8004 §3.10: `*STB?` answers `65` (bit 6 MSS and bit 0 set; bit 0 is
// the interlock summary).
TEST(AclValues, StatusByteOfTheManual) {
  auto stb = parse_number("65");
  ASSERT_TRUE(stb.ok());
  EXPECT_EQ(static_cast<int>(*stb) & 1, 1);
  EXPECT_EQ(static_cast<int>(*stb) & 0x40, 0x40);
}

// TM-8004 §4.7: `:M? 1;:M? 2;:M? 3` answers `P;R;P`; field firmware spells
// the modes out.
TEST(AclValues, ModesShortLongAndUnknown) {
  const auto fields = split_fields("P;R;P");
  ASSERT_EQ(fields.size(), 3u);
  EXPECT_EQ(parse_mode(fields[0]).mode, TableMode::kPosition);
  EXPECT_EQ(parse_mode(fields[1]).mode, TableMode::kRate);
  EXPECT_EQ(parse_mode("O").mode, TableMode::kOff);
  EXPECT_EQ(parse_mode("Position").mode, TableMode::kPosition);
  EXPECT_EQ(parse_mode("rate").mode, TableMode::kRate);
  EXPECT_EQ(parse_mode("OFF").mode, TableMode::kOff);
  const auto synth = parse_mode("Synthesis");
  EXPECT_EQ(synth.mode, TableMode::kUnknown);
  EXPECT_EQ(synth.text, "Synthesis");
}

// TM-8004 §4.5.3: the interlock state is `{Close|Open|Fault}`; field
// firmware answers `Closed`. Both are a closed (servoed) interlock.
TEST(AclValues, TheManualsCloseAndTheFieldsClosed) {
  EXPECT_EQ(*parse_interlock("Close"), TableInterlock::kClosed);
  EXPECT_EQ(*parse_interlock(" close\r\n"), TableInterlock::kClosed);
  EXPECT_EQ(*parse_interlock("Closed"), TableInterlock::kClosed);
  auto s = parse_state("R;Close;10;0");
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_EQ(s->interlock, TableInterlock::kClosed);
  EXPECT_FALSE(parse_interlock("Clos").ok());
  EXPECT_FALSE(parse_interlock("Closes").ok());
}

// acutrol3000.py: `if inst.query(":interlock? 1") == "Fault\n"`.
TEST(AclValues, InterlockWords) {
  EXPECT_EQ(*parse_interlock("Fault\n"), TableInterlock::kFault);
  EXPECT_EQ(*parse_interlock("closed"), TableInterlock::kClosed);
  EXPECT_EQ(*parse_interlock("OPEN"), TableInterlock::kOpen);
  auto bad = parse_interlock("Ajar");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("Ajar"), std::string::npos);
}

TEST(AclValues, StateOfTheChainedQuery) {
  auto s = parse_state("Rate;Closed;10.0001;123.4");
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_EQ(s->mode, TableMode::kRate);
  EXPECT_EQ(s->mode_text, "Rate");
  EXPECT_EQ(s->interlock, TableInterlock::kClosed);
  EXPECT_DOUBLE_EQ(s->rate_dps, 10.0001);
  EXPECT_DOUBLE_EQ(s->position_deg, 123.4);
  EXPECT_EQ(s->fault, "");
  auto f = parse_state("O;Fault;0.0;12.0");
  ASSERT_TRUE(f.ok());
  EXPECT_EQ(f->interlock, TableInterlock::kFault);
  EXPECT_FALSE(f->fault.empty());
  EXPECT_FALSE(parse_state("Rate;Closed;10.0001").ok());
  EXPECT_FALSE(parse_state("Rate;Closed;ten;123.4").ok());
  EXPECT_FALSE(parse_state("Rate;Shut;10;123.4").ok());
}

// ---------------------------------------------------------------- framing

// ac117.json: each startup command (`:utility:lockout on`, `:interlock:open
// 1`, `:interlock:reset 1`, `:interlock:close 1`) expects `OK`, which
// acutrol.py reads by skipping the reply's first 8 bytes: the ascii framing's
// header.
TEST(AclFraming, StartupCommandsAnsweredOk) {
  std::string stream;
  for (int i = 0; i < 4; ++i) stream += ascii_frame(0, "OK");
  ASSERT_EQ(stream.substr(8, 2), "OK");  // what acutrol.py sees
  const auto replies = decode_all(ReplyFraming::kAscii, stream, stream.size());
  ASSERT_EQ(replies.size(), 4u);
  for (const auto& r : replies) {
    EXPECT_EQ(r.code, 0u);
    EXPECT_EQ(r.payload, "OK");
  }
}

TEST(AclFraming, EveryFramingWholeAndByteByByte) {
  const std::string payload = "Rate;Closed;10.0001;123.4";
  struct Case {
    ReplyFraming framing;
    std::string stream;
  } cases[] = {
      {ReplyFraming::kAscii, ascii_frame(0, payload) + ascii_frame(12, "")},
      {ReplyFraming::kBinaryLe, binary_frame(0, payload, true) + binary_frame(12, "", true)},
      {ReplyFraming::kBinaryBe, binary_frame(0, payload, false) + binary_frame(12, "", false)},
  };
  for (const auto& c : cases) {
    for (std::size_t chunk : {c.stream.size(), std::size_t{1}, std::size_t{3}}) {
      const auto replies = decode_all(c.framing, c.stream, chunk);
      ASSERT_EQ(replies.size(), 2u) << to_string(c.framing) << " chunk " << chunk;
      EXPECT_EQ(replies[0].code, 0u);
      EXPECT_EQ(replies[0].payload, payload);
      EXPECT_EQ(replies[1].code, 12u);
      EXPECT_EQ(replies[1].payload, "");
    }
  }
  const auto lines = decode_all(ReplyFraming::kLine, payload + "\r\nFault\n", 1);
  ASSERT_EQ(lines.size(), 2u);
  EXPECT_EQ(lines[0].payload, payload);
  EXPECT_EQ(lines[1].payload, "Fault");
}

TEST(AclFraming, TrailingLineEndsAreTolerated) {
  // Counted in the length, or sent after the payload uncounted.
  const std::string stream =
      ascii_frame(0, "1500.0\r\n") + ascii_frame(0, "OK") + "\r\n" + ascii_frame(0, "65\n");
  const auto replies = decode_all(ReplyFraming::kAscii, stream, 1);
  ASSERT_EQ(replies.size(), 3u);
  EXPECT_EQ(replies[0].payload, "1500.0");
  EXPECT_EQ(replies[1].payload, "OK");
  EXPECT_EQ(replies[2].payload, "65");
  const auto bin = decode_all(ReplyFraming::kBinaryBe, binary_frame(0, "OK\r\n", false), 2);
  ASSERT_EQ(bin.size(), 1u);
  EXPECT_EQ(bin[0].payload, "OK");
}

TEST(AclFraming, GarbageIsAnErrorAndTheDecoderStartsAfresh) {
  for (const std::string& bad : {std::string("OK\r\n"), std::string("0000x002OK"),
                                 std::string("00005000") + std::string(10, 'a')}) {
    ReplyDecoder d(ReplyFraming::kAscii);
    d.feed(bad);
    auto r = d.next();
    ASSERT_FALSE(r.ok()) << bad;
    EXPECT_NE(r.error().message.find("malformed"), std::string::npos);
    EXPECT_TRUE(r.error().transient);
    EXPECT_EQ(d.buffered(), 0u);
    d.feed(ascii_frame(0, "OK"));  // a fresh connection's reply decodes
    auto ok = d.next();
    ASSERT_TRUE(ok.ok() && *ok);
    EXPECT_EQ((*ok)->payload, "OK");
  }
  // A non-digit is caught as soon as it arrives, before 8 bytes are there.
  ReplyDecoder early(ReplyFraming::kAscii);
  early.feed("00?");
  EXPECT_FALSE(early.next().ok());
  // Oversize binary length; an endless line.
  ReplyDecoder bin(ReplyFraming::kBinaryLe);
  bin.feed(binary_frame(0, "", true).substr(0, 4) + std::string("\xff\xff\xff\x7f", 4));
  EXPECT_FALSE(bin.next().ok());
  ReplyDecoder line(ReplyFraming::kLine);
  line.feed(std::string(kMaxPayloadBytes + 1, 'x'));
  EXPECT_FALSE(line.next().ok());
}

TEST(AclFraming, IncompleteFramesWait) {
  ReplyDecoder d(ReplyFraming::kAscii);
  d.feed("00000006150");
  auto r = d.next();
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());
  d.feed("0.0");
  r = d.next();
  ASSERT_TRUE(r.ok() && *r);
  EXPECT_EQ((*r)->payload, "1500.0");
}

// The first reply of a connection (to *IDN?, TM-8004 §3.4's example
// answer) in each framing, whole and growing byte by byte: undecided
// (nullopt) until complete, then the framing, the payload and the bytes it
// took; what follows it is left for the decoder.
TEST(AclFirstReply, EachFramingIsRecognised) {
  const std::string idn = "Acutronic R&D USA,Acutrol3000,0,A8800-001-01.000-a";
  struct Case {
    ReplyFraming framing;
    std::string bytes;
  };
  const std::vector<Case> cases{
      {ReplyFraming::kAscii, ascii_frame(0, idn)},
      {ReplyFraming::kAscii, ascii_frame(0, idn + "\r\n")},  // CR LF counted
      {ReplyFraming::kBinaryLe, binary_frame(0, idn, true)},
      {ReplyFraming::kBinaryBe, binary_frame(0, idn, false)},
      {ReplyFraming::kLine, idn + "\r\n"},
      {ReplyFraming::kLine, idn + "\n"},
  };
  const std::string next = ascii_frame(0, "OK");
  for (const Case& c : cases) {
    const std::string where = std::string(to_string(c.framing)) + " " + describe_bytes(c.bytes);
    for (std::size_t n = 0; n < c.bytes.size(); ++n) {
      auto partial = detect_first_reply(std::string_view(c.bytes).substr(0, n));
      ASSERT_TRUE(partial.ok()) << where << " at " << n << ": " << partial.error().message;
      if (c.framing != ReplyFraming::kLine || n < idn.size()) {
        EXPECT_FALSE(partial->has_value()) << where << " decided at " << n;
      }
    }
    auto r = detect_first_reply(c.bytes + next);
    ASSERT_TRUE(r.ok()) << where << ": " << r.error().message;
    ASSERT_TRUE(r->has_value()) << where;
    EXPECT_EQ((*r)->framing, c.framing) << where;
    EXPECT_EQ((*r)->reply.code, 0u) << where;
    EXPECT_EQ((*r)->reply.payload, idn) << where;
    EXPECT_EQ((*r)->consumed, c.bytes.size()) << where;
  }
  // A CR LF left over before the reply is skipped.
  auto r = detect_first_reply("\r\n" + ascii_frame(0, idn));
  ASSERT_TRUE(r.ok() && r->has_value());
  EXPECT_EQ((*r)->framing, ReplyFraming::kAscii);
  EXPECT_EQ((*r)->consumed, 2 + 8 + idn.size());
}

// Bytes that fit no framing are refused, named byte by byte: printable ones
// as they are, the others escaped.
TEST(AclFirstReply, AnUnknownFramingNamesWhatWasReceived) {
  // A 16-bit byte-swapped error word and a 16-bit length, say: no framing
  // we know.
  const std::string odd = std::string("\x00\x00\x05\x00", 4) + "ACUTR";
  auto r = detect_first_reply(odd + std::string("\xff\xfe\x01\x02", 4));
  ASSERT_FALSE(r.ok());
  const std::string& m = r.error().message;
  EXPECT_NE(m.find("fits no known framing"), std::string::npos) << m;
  EXPECT_NE(m.find(R"("\x00\x00\x05\x00ACUTR\xff\xfe\x01\x02" (13 bytes))"), std::string::npos)
      << m;
  // Text with a control byte in it, before any line end.
  auto t = detect_first_reply(std::string("Acu\x07trol\n"));
  ASSERT_FALSE(t.ok());
  EXPECT_NE(t.error().message.find(R"("Acu\x07trol\x0a" (9 bytes))"), std::string::npos)
      << t.error().message;
  // An ASCII header whose payload is not text.
  auto a = detect_first_reply(std::string("00000003\x01\x02\x03", 11));
  ASSERT_FALSE(a.ok());
  EXPECT_NE(a.error().message.find("\\x01\\x02\\x03"), std::string::npos) << a.error().message;
  EXPECT_EQ(describe_bytes(std::string(70, 'x'), 4), R"("xxxx..." (70 bytes))");
  EXPECT_EQ(describe_bytes("a\"b\\"), R"("a\"b\\" (4 bytes))");
}

TEST(AclFraming, FramingNames) {
  for (const char* n : {"ascii", "binary-le", "binary-be", "line"}) {
    auto f = parse_reply_framing(n);
    ASSERT_TRUE(f.ok());
    EXPECT_EQ(to_string(*f), n);
  }
  auto bad = parse_reply_framing("hex");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("hex"), std::string::npos);
}

}  // namespace
}  // namespace gyrotherm::drivers::acl
