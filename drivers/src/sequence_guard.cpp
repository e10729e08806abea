#include "gyrotherm/drivers/sequence_guard.h"

#include <fmt/format.h>

namespace gyrotherm::drivers {

std::string sequence_reject_reason(std::string_view what, uint64_t seq,
                                   std::optional<uint64_t> after,
                                   std::optional<uint64_t> next_seq) {
  const std::string why = next_seq
                              ? fmt::format("the next frame's counter is {}", *next_seq)
                              : std::string("no frame came after it before the line was reopened");
  if (!after) {
    return fmt::format(
        "{} dropped: its counter {} starts the stream and the next frame does not follow it ({})",
        what, seq, why);
  }
  return fmt::format("{} dropped: its counter {} jumps from {} and no frame confirms it ({})", what,
                     seq, *after, why);
}

}  // namespace gyrotherm::drivers
