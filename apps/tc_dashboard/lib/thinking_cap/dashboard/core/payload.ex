defmodule ThinkingCap.Dashboard.Core.Payload do
  @moduledoc false
  # A stream's payload as the page reads it (JSON), for the live
  # telemetry and the black box's timeline alike: floats to 0.1 mm,
  # 0.1 mrad, 0.1 ms (what a screen can show, in a third of the text a
  # browser must parse); a learned map of more than @map_cells cells
  # shrunk for display, its cells in base64.
  require Logger

  alias ThinkingCap.Dashboard.Core.JSON
  alias ThinkingCap.Navigation.OccupancyGrid

  @map_cells 250_000

  @doc "The most cells of a map sent to the page."
  @spec map_cells() :: pos_integer()
  def map_cells, do: @map_cells

  @doc "`payload` of the stream `key` as JSON, or `\"null\"` (logged) when it cannot be."
  @spec encode(String.t(), term()) :: binary()
  def encode(key, %OccupancyGrid{} = map) do
    small = OccupancyGrid.shrink(map, @map_cells)
    encode(key, %{Map.from_struct(small) | data: Base.encode64(small.data)})
  end

  def encode(key, payload) do
    payload |> JSON.encode!(decimals: 4) |> IO.iodata_to_binary()
  rescue
    e ->
      Logger.warning("dashboard: #{key} could not be encoded: #{Exception.message(e)}")
      "null"
  end
end
