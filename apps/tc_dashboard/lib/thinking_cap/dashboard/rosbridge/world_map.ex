defmodule ThinkingCap.Dashboard.Rosbridge.WorldMap do
  @moduledoc false
  # `/map`: the dashboard's world (its `world` option, a WDF path or
  # struct) as occupancy cells. A WDF that imports a ROS map gives that
  # map's cells as they are (−1 unknown, 0..100); otherwise its walls,
  # obstacles and closed doors are rasterized at 5 cm
  # (ThinkingCap.Navigation.Maps.grid_from_wdf/2: 100 blocked, 0 free). The
  # doors are drawn as the WDF states them, not as they are now.

  alias ThinkingCap.Config
  alias ThinkingCap.Config.{RosMap, WDF}
  alias ThinkingCap.Navigation.Maps

  @type cells :: %{
          width: pos_integer(),
          height: pos_integer(),
          resolution: float(),
          origin: {float(), float(), float()},
          data: binary()
        }

  @doc "The cells of the world, or why there are none."
  @spec cells(term()) :: {:ok, cells()} | {:error, String.t()}
  def cells(nil), do: {:error, "the dashboard has no world: no /map"}

  def cells(path) when is_binary(path) do
    case Config.read(path) do
      {:ok, %WDF{} = wdf} ->
        cells(wdf)

      {:ok, _other} ->
        {:error, "#{path} is not a WDF"}

      {:error, errors} ->
        {:error, "the world could not be read: " <> Config.format_errors(errors)}
    end
  end

  def cells(%WDF{grid: %RosMap{} = map}) do
    {:ok,
     %{
       width: map.width,
       height: map.height,
       resolution: map.resolution,
       origin: map.origin,
       data: map.data
     }}
  end

  def cells(%WDF{} = wdf) do
    grid = Maps.grid_from_wdf(wdf)
    {ox, oy} = grid.origin
    data = for <<c <- grid.cells>>, into: <<>>, do: if(c == 0, do: <<0>>, else: <<100>>)

    {:ok,
     %{
       width: grid.width,
       height: grid.height,
       resolution: grid.resolution,
       origin: {ox, oy, 0.0},
       data: data
     }}
  rescue
    e in ArgumentError -> {:error, "the world could not be rasterized: #{Exception.message(e)}"}
  end

  def cells(_other), do: {:error, "the dashboard's world is not a WDF"}
end
