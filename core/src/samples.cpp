#include "gyrotherm/core/samples.h"

namespace gyrotherm {

std::string_view to_string(ChannelKind kind) {
  switch (kind) {
    case ChannelKind::kRate:
      return "rate";
    case ChannelKind::kAccel:
      return "accel";
    case ChannelKind::kTemperature:
      return "temperature";
    case ChannelKind::kStatus:
      return "status";
    case ChannelKind::kOther:
      break;
  }
  return "other";
}

std::optional<ChannelKind> channel_kind_from_string(std::string_view s) {
  for (auto k : {ChannelKind::kRate, ChannelKind::kAccel, ChannelKind::kTemperature,
                 ChannelKind::kStatus, ChannelKind::kOther}) {
    if (to_string(k) == s) return k;
  }
  return std::nullopt;
}

}  // namespace gyrotherm
