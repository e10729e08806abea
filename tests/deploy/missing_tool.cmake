# A test that fails with MESSAGE: stands in for a check whose tool is missing
# (cmake -DMESSAGE=... -P missing_tool.cmake).
message(FATAL_ERROR "${MESSAGE}")
