// Read one MCAP file of a rosbag2 bag as Foxglove does, and print what was found as JSON.
//
// Usage: node check_bag.js FILE.mcap [MAX_SKEW_NS]
//
// Both of Foxglove's MCAP readers (@mcap/core's McapIndexedReader, through the summary, and
// McapStreamReader, front to back), with the zstd/lz4 handlers of @mcap/support. Every message
// is decoded with @foxglove/rosmsg2-serialization from the channel's ros2msg schema (parsed by
// @foxglove/rosmsg). Exit status 1, with the reasons in "errors", if a message does not decode,
// the two readers disagree, or a message's publish_time is further than MAX_SKEW_NS (default
// 1 s) from its log_time.
'use strict';

const fs = require('node:fs');
const { McapIndexedReader, McapStreamReader } = require('@mcap/core');
const { loadDecompressHandlers } = require('@mcap/support');
const { parse } = require('@foxglove/rosmsg');
const { MessageReader } = require('@foxglove/rosmsg2-serialization');

function fileReadable(handle, size) {
  return {
    size: async () => BigInt(size),
    read: async (offset, length) => {
      const buffer = new Uint8Array(Number(length));
      const { bytesRead } = await handle.read(buffer, 0, Number(length), Number(offset));
      return buffer.subarray(0, bytesRead);
    },
  };
}

function decoderFor(readers, schema) {
  if (!readers.has(schema.id)) {
    if (schema.encoding !== 'ros2msg') {
      throw new Error(`schema ${schema.name}: encoding ${schema.encoding}, not ros2msg`);
    }
    const text = new TextDecoder().decode(schema.data);
    readers.set(schema.id, new MessageReader(parse(text, { ros2: true })));
  }
  return readers.get(schema.id);
}

function tally(result, message, channel, schema, readers, maxSkew) {
  result.messages += 1;
  result.topics[channel.topic] = (result.topics[channel.topic] || 0) + 1;
  try {
    const decoded = decoderFor(readers, schema).readMessage(message.data);
    if (decoded === undefined || decoded === null) {
      throw new Error('nothing decoded');
    }
    result.decoded += 1;
  } catch (error) {
    result.errors.push(`${channel.topic} #${message.sequence}: ${error.message}`);
  }
  const skew = message.publishTime - message.logTime;
  const magnitude = skew < 0n ? -skew : skew;
  if (magnitude > result.maxSkewNs) {
    result.maxSkewNs = magnitude;
  }
  if (magnitude > maxSkew) {
    result.skewed += 1;
  }
}

async function readIndexed(path, decompressHandlers, maxSkew) {
  const handle = await fs.promises.open(path, 'r');
  try {
    const { size } = await handle.stat();
    const reader = await McapIndexedReader.Initialize({
      readable: fileReadable(handle, size), decompressHandlers,
    });
    const result = {
      messages: 0, decoded: 0, skewed: 0, maxSkewNs: 0n, topics: {}, errors: [],
      rosbag2Records: 0, profile: reader.header.profile,
    };
    const readers = new Map();
    for await (const message of reader.readMessages({ validateCrcs: true })) {
      const channel = reader.channelsById.get(message.channelId);
      tally(result, message, channel, reader.schemasById.get(channel.schemaId), readers,
        maxSkew);
    }
    for await (const record of reader.readMetadata({ name: 'rosbag2' })) {
      result.rosbag2Records += 1;
      result.lastRosbag2 = record.metadata.get('serialized_metadata') || '';
    }
    return result;
  } finally {
    await handle.close();
  }
}

function readStreaming(path, decompressHandlers, maxSkew) {
  const reader = new McapStreamReader({ decompressHandlers, validateCrcs: true });
  reader.append(new Uint8Array(fs.readFileSync(path)));
  const result = {
    messages: 0, decoded: 0, skewed: 0, maxSkewNs: 0n, topics: {}, errors: [],
    rosbag2Records: 0,
  };
  const schemas = new Map();
  const channels = new Map();
  const readers = new Map();
  for (let record; (record = reader.nextRecord());) {
    if (record.type === 'Schema') {
      schemas.set(record.id, record);
    } else if (record.type === 'Channel') {
      channels.set(record.id, record);
    } else if (record.type === 'Message') {
      const channel = channels.get(record.channelId);
      tally(result, record, channel, schemas.get(channel.schemaId), readers, maxSkew);
    } else if (record.type === 'Metadata' && record.name === 'rosbag2') {
      result.rosbag2Records += 1;
      result.lastRosbag2 = record.metadata.get('serialized_metadata') || '';
    }
  }
  result.complete = reader.done();
  return result;
}

async function main() {
  const [path, skewArgument] = process.argv.slice(2);
  if (!path) {
    console.error('usage: node check_bag.js FILE.mcap [MAX_SKEW_NS]');
    process.exit(2);
  }
  const maxSkew = BigInt(skewArgument || '1000000000');
  const decompressHandlers = await loadDecompressHandlers();
  const indexed = await readIndexed(path, decompressHandlers, maxSkew);
  const streaming = readStreaming(path, decompressHandlers, maxSkew);
  const errors = [...indexed.errors, ...streaming.errors];
  if (indexed.messages !== streaming.messages) {
    errors.push(`indexed reader read ${indexed.messages} messages, streaming ${streaming.messages}`);
  }
  for (const [name, result] of [['indexed', indexed], ['streaming', streaming]]) {
    if (result.decoded !== result.messages) {
      errors.push(`${name}: decoded ${result.decoded} of ${result.messages} messages`);
    }
    if (result.skewed) {
      errors.push(`${name}: ${result.skewed} messages with publish_time more than ` +
        `${maxSkew} ns from log_time`);
    }
  }
  if (!streaming.complete) {
    errors.push('streaming reader did not reach the end of the file');
  }
  const json = JSON.stringify({ indexed, streaming, errors },
    (key, value) => (typeof value === 'bigint' ? Number(value) : value));
  console.log(json);
  process.exit(errors.length ? 1 : 0);
}

main().catch((error) => {
  console.log(JSON.stringify({ errors: [String(error && error.stack || error)] }));
  process.exit(1);
});
