defmodule ThinkingCap.Dashboard.Rosbridge.Frames do
  @moduledoc false
  # The frames a rosbridge session sends (JSON text): `publish` messages
  # and `status` messages, the latter only at or above the level the client
  # set (`set_level`; `error` until then).

  alias ThinkingCap.Dashboard.Core.JSON

  @levels %{"info" => 0, "warning" => 1, "error" => 2, "none" => 3}

  @type level :: 0..3
  @type id :: String.t() | integer() | nil

  @doc "The number of a status level's name (`\"error\"` → 2), or nil."
  @spec level(term()) :: level() | nil
  def level(name), do: @levels[name]

  @doc "A `publish` frame of `msg` on topic `name`."
  @spec publish(String.t(), map()) :: iodata()
  def publish(name, msg), do: JSON.encode!(%{op: "publish", topic: name, msg: msg})

  @doc "A `status` frame in a list, or none when `level` is below the client's `min_level`."
  @spec status(level(), String.t(), String.t(), id()) :: [iodata()]
  def status(min_level, level, message, id) do
    if @levels[level] >= min_level, do: [status_frame(level, message, id)], else: []
  end

  @doc "A `status` frame, whatever the client's level."
  @spec status_frame(String.t(), String.t(), id()) :: iodata()
  def status_frame(level, message, id),
    do: JSON.encode!(with_id(%{op: "status", level: level, msg: message}, id))

  @doc "A reply with the request's `id` (none when the request had none)."
  @spec with_id(map(), id()) :: map()
  def with_id(map, nil), do: map
  def with_id(map, id), do: Map.put(map, :id, id)

  @doc "The id of a client message, when it is a short string or an integer."
  @spec id_of(map()) :: id()
  def id_of(%{"id" => id}) when is_binary(id) and byte_size(id) <= 256, do: id
  def id_of(%{"id" => id}) when is_integer(id) and abs(id) < 1_000_000_000_000_000_000, do: id
  def id_of(_), do: nil

  @doc "A client's value, shortened for a status message."
  @spec short(term()) :: String.t()
  def short(term), do: inspect(term, limit: 5, printable_limit: 60)
end
