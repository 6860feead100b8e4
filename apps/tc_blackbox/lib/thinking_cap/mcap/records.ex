defmodule ThinkingCap.MCAP.Schema do
  @moduledoc "An MCAP Schema record: how a channel's messages are laid out."
  @enforce_keys [:id, :name, :encoding, :data]
  defstruct [:id, :name, :encoding, :data]

  @type t :: %__MODULE__{
          id: 1..65_535,
          name: String.t(),
          encoding: String.t(),
          data: binary()
        }
end

defmodule ThinkingCap.MCAP.Channel do
  @moduledoc "An MCAP Channel record: a topic, its schema and its message encoding."
  @enforce_keys [:id, :schema_id, :topic, :message_encoding]
  defstruct [:id, :schema_id, :topic, :message_encoding, metadata: %{}]

  @type t :: %__MODULE__{
          id: 0..65_535,
          schema_id: 0..65_535,
          topic: String.t(),
          message_encoding: String.t(),
          metadata: %{String.t() => String.t()}
        }
end

defmodule ThinkingCap.MCAP.Message do
  @moduledoc "An MCAP Message record: one message on a channel, with its times in ns."
  @enforce_keys [:channel_id, :log_time, :publish_time, :data]
  defstruct [:channel_id, :log_time, :publish_time, :data, sequence: 0]

  @type t :: %__MODULE__{
          channel_id: 0..65_535,
          sequence: non_neg_integer(),
          log_time: ThinkingCap.MCAP.time(),
          publish_time: ThinkingCap.MCAP.time(),
          data: binary()
        }
end

defmodule ThinkingCap.MCAP.ChunkIndex do
  @moduledoc """
  An MCAP Chunk Index record (in the summary): where a chunk and its
  message indexes are, the span of its messages' log times, its sizes.
  """
  @enforce_keys [:chunk_start_offset, :chunk_length]
  defstruct [
    :chunk_start_offset,
    :chunk_length,
    message_start_time: 0,
    message_end_time: 0,
    message_index_offsets: %{},
    message_index_length: 0,
    compression: "",
    compressed_size: 0,
    uncompressed_size: 0
  ]

  @type t :: %__MODULE__{
          message_start_time: ThinkingCap.MCAP.time(),
          message_end_time: ThinkingCap.MCAP.time(),
          chunk_start_offset: non_neg_integer(),
          chunk_length: non_neg_integer(),
          message_index_offsets: %{non_neg_integer() => non_neg_integer()},
          message_index_length: non_neg_integer(),
          compression: String.t(),
          compressed_size: non_neg_integer(),
          uncompressed_size: non_neg_integer()
        }
end

defmodule ThinkingCap.MCAP.Statistics do
  @moduledoc "An MCAP Statistics record (in the summary): counts and the span of log times."
  defstruct message_count: 0,
            schema_count: 0,
            channel_count: 0,
            attachment_count: 0,
            metadata_count: 0,
            chunk_count: 0,
            message_start_time: 0,
            message_end_time: 0,
            channel_message_counts: %{}

  @type t :: %__MODULE__{
          message_count: non_neg_integer(),
          schema_count: non_neg_integer(),
          channel_count: non_neg_integer(),
          attachment_count: non_neg_integer(),
          metadata_count: non_neg_integer(),
          chunk_count: non_neg_integer(),
          message_start_time: ThinkingCap.MCAP.time(),
          message_end_time: ThinkingCap.MCAP.time(),
          channel_message_counts: %{non_neg_integer() => non_neg_integer()}
        }
end
