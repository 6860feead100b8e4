defmodule ThinkingCap.Config.RosMap do
  @moduledoc """
  Imports a ROS `map_server` occupancy map: a YAML file (`image`,
  `resolution`, `origin`, `negate`, `occupied_thresh`, `free_thresh`,
  `mode`) and the binary PGM (P5) image it names.

  The rules are nav2 `map_io`'s for `mode: trinary` (the default): a pixel
  value v gives p = (255 − v)/255 (v/255 when `negate` is 1); the cell is
  occupied (100) when p > `occupied_thresh`, free (0) when p <
  `free_thresh`, unknown (−1) otherwise. Image row 0 is the top of the
  picture and grid row 0 the bottom (y grows upwards), so rows are flipped.
  `origin` is the pose of the lower-left cell. Other modes (`scale`, `raw`)
  and other image formats are refused with an error saying so.
  """

  @enforce_keys [:file, :width, :height, :resolution, :origin, :data]
  defstruct [:file, :width, :height, :resolution, :origin, :data]

  @typedoc """
  `data` holds one signed byte per cell (−1, 0..100), row-major from the
  bottom row: cell (col, row) is byte `row * width + col`.
  """
  @type t :: %__MODULE__{
          file: Path.t(),
          width: pos_integer(),
          height: pos_integer(),
          resolution: float(),
          origin: {float(), float(), float()},
          data: binary()
        }

  @doc "Loads the map described by the YAML file at `path`."
  @spec load(Path.t()) :: {:ok, t()} | {:error, String.t()}
  def load(path) do
    with {:ok, yaml} <- read(path),
         {:ok, params} <- parse_yaml(yaml, path),
         image = Path.expand(params.image, Path.dirname(path)),
         {:ok, pgm} <- read(image),
         {:ok, width, height, pixels} <- parse_pgm(pgm, image) do
      {:ok,
       %__MODULE__{
         file: path,
         width: width,
         height: height,
         resolution: params.resolution,
         origin: params.origin,
         data: to_cells(pixels, width, height, params)
       }}
    end
  end

  @doc "The occupancy of cell (`col`, `row`): −1 unknown, 0 free .. 100 occupied."
  @spec cell(t(), non_neg_integer(), non_neg_integer()) :: -1..100
  def cell(%__MODULE__{width: w, height: h, data: data}, col, row)
      when col in 0..(w - 1) and row in 0..(h - 1) do
    <<_::binary-size(row * w + col), v::signed-8, _::binary>> = data
    v
  end

  @doc """
  Saves a map as `map_saver` does: the YAML file at `yaml_path` and, beside
  it, a binary PGM of the same base name. `map` is a `t()` or any map with
  `width`, `height`, `resolution`, `origin` (`{x, y}` or `{x, y, yaw}`) and
  `data` (one byte per cell in this module's layout; 1..99 count as
  occupied from 65 and free up to 19, as map_saver's default thresholds).
  Cells are written trinary: occupied black (0), free white (254), unknown
  grey (205); so `load/1` gives back the trinary map exactly.
  """
  @spec save(map(), Path.t()) :: :ok | {:error, String.t()}
  def save(%{width: w, height: h, resolution: res, origin: origin, data: data}, yaml_path)
      when is_integer(w) and w > 0 and is_integer(h) and h > 0 and byte_size(data) == w * h do
    {x, y, yaw} =
      case origin do
        {x, y} -> {x, y, 0.0}
        {x, y, yaw} -> {x, y, yaw}
      end

    pgm = Path.rootname(yaml_path) <> ".pgm"

    rows =
      for row <- (h - 1)..0//-1 do
        for <<v::signed-8 <- binary_part(data, row * w, w)>>, into: <<>>, do: <<pixel(v)>>
      end

    yaml = """
    image: #{Path.basename(pgm)}
    mode: trinary
    resolution: #{float(res)}
    origin: [#{float(x)}, #{float(y)}, #{float(yaw)}]
    negate: 0
    occupied_thresh: 0.65
    free_thresh: 0.196
    """

    with :ok <- write(pgm, ["P5\n# ThinkingCap map\n#{w} #{h}\n255\n" | rows]),
         :ok <- write(yaml_path, yaml) do
      :ok
    end
  end

  def save(_map, yaml_path),
    do: {:error, "#{yaml_path}: not saved: the map's data does not hold width × height cells"}

  # map_saver's trinary colours and default thresholds
  defp pixel(v) when v < 0, do: 205
  defp pixel(v) when v >= 65, do: 0
  defp pixel(v) when v <= 19, do: 254
  defp pixel(_v), do: 205

  defp float(v), do: :erlang.float_to_binary(v * 1.0, [:short])

  defp write(path, iodata) do
    case File.write(path, iodata) do
      :ok -> :ok
      {:error, reason} -> {:error, "cannot write #{path}: #{:file.format_error(reason)}"}
    end
  end

  @doc "The grid as a list of rows, bottom row first (for tests and tools)."
  @spec rows(t()) :: [[integer()]]
  def rows(%__MODULE__{width: w, data: data}) do
    for <<row::binary-size(w) <- data>>, do: for(<<v::signed-8 <- row>>, do: v)
  end

  defp read(path) do
    case File.read(path) do
      {:ok, bin} -> {:ok, bin}
      {:error, reason} -> {:error, "cannot read #{path}: #{:file.format_error(reason)}"}
    end
  end

  ## YAML

  defp parse_yaml(text, path) do
    case ensure_yaml() && :fast_yaml.decode(text) do
      false -> {:error, "#{path}: the YAML reader (Debian's erlang-p1-yaml) is not installed"}
      {:ok, [doc]} when is_list(doc) -> yaml_params(Map.new(doc), path)
      {:ok, _} -> {:error, "#{path}: expected one YAML mapping of map parameters"}
      {:error, reason} -> {:error, "#{path}: invalid YAML: #{inspect(reason)}"}
    end
  end

  # Debian installs fast_yaml as lib/p1_yaml-VSN: a release (whose code
  # path holds only its own libraries) finds it there.
  defp ensure_yaml do
    match?({:ok, _}, Application.ensure_all_started(:fast_yaml)) or
      (Enum.each(
         Path.wildcard("{#{:code.lib_dir()},/usr/lib/erlang/lib}/{p1_yaml,p1_utils}-*/ebin"),
         &Code.append_path/1
       ) && match?({:ok, _}, Application.ensure_all_started(:fast_yaml)))
  end

  defp yaml_params(doc, path) do
    with {:ok, image} <- field(doc, path, "image", &is_binary/1, "a file name"),
         {:ok, res} <-
           field(
             doc,
             path,
             "resolution",
             &(is_number(&1) and &1 > 0),
             "a positive number (m/cell)"
           ),
         {:ok, origin} <- field(doc, path, "origin", &origin?/1, "[x, y, yaw]"),
         {:ok, negate} <- field(doc, path, "negate", &(&1 in [0, 1]), "0 or 1", 0),
         {:ok, occ} <-
           field(doc, path, "occupied_thresh", &probability?/1, "a number from 0 to 1", 0.65),
         {:ok, free} <-
           field(doc, path, "free_thresh", &probability?/1, "a number from 0 to 1", 0.196),
         {:ok, mode} <- field(doc, path, "mode", &is_binary/1, "a string", "trinary") do
      if mode == "trinary" do
        [x, y, yaw] = origin

        {:ok,
         %{
           image: image,
           resolution: res / 1,
           origin: {x / 1, y / 1, yaw / 1},
           negate: negate,
           occupied: occ,
           free: free
         }}
      else
        {:error, "#{path}: mode #{inspect(mode)} is not supported (only \"trinary\" is)"}
      end
    end
  end

  defp field(doc, path, key, valid?, expected, default \\ :required) do
    case Map.fetch(doc, key) do
      {:ok, value} ->
        if valid?.(value),
          do: {:ok, value},
          else: {:error, "#{path}: #{key}: expected #{expected}, got #{inspect(value)}"}

      :error when default == :required ->
        {:error, "#{path}: missing #{key}"}

      :error ->
        {:ok, default}
    end
  end

  defp origin?([x, y, yaw]), do: is_number(x) and is_number(y) and is_number(yaw)
  defp origin?(_), do: false
  defp probability?(v), do: is_number(v) and v >= 0 and v <= 1

  ## PGM

  defp parse_pgm(<<"P5", rest::binary>>, path) do
    with {:ok, width, rest} <- header_int(rest, path, "width"),
         {:ok, height, rest} <- header_int(rest, path, "height"),
         {:ok, maxval, <<sep, pixels::binary>>} when sep in ~c" \t\r\n" <-
           header_int(rest, path, "maximum value") do
      cond do
        maxval != 255 ->
          {:error, "#{path}: only 8-bit PGM (maximum value 255) is supported, got #{maxval}"}

        byte_size(pixels) < width * height ->
          {:error,
           "#{path}: expected #{width * height} pixels (#{width}x#{height}), found #{byte_size(pixels)}"}

        true ->
          {:ok, width, height, binary_part(pixels, 0, width * height)}
      end
    else
      {:ok, _maxval, _rest} -> {:error, "#{path}: truncated PGM header"}
      error -> error
    end
  end

  defp parse_pgm(<<magic::binary-size(2), _::binary>>, path),
    do: {:error, "#{path}: expected a binary PGM image (P5), found magic #{inspect(magic)}"}

  defp parse_pgm(_, path), do: {:error, "#{path}: not a PGM image"}

  # whitespace and # comments may come before each header number
  defp header_int(<<c, rest::binary>>, path, what) when c in ~c" \t\r\n",
    do: header_int(rest, path, what)

  defp header_int(<<"#", rest::binary>>, path, what) do
    case :binary.split(rest, "\n") do
      [_comment, rest] -> header_int(rest, path, what)
      [_] -> {:error, "#{path}: truncated PGM header"}
    end
  end

  defp header_int(bin, path, what) do
    case Integer.parse(bin) do
      {n, rest} when n > 0 -> {:ok, n, rest}
      _ -> {:error, "#{path}: bad PGM header: expected the #{what}"}
    end
  end

  ## Cells

  defp to_cells(pixels, width, height, params) do
    lut = List.to_tuple(for v <- 0..255, do: trinary(v, params))

    for row <- (height - 1)..0//-1, into: <<>> do
      for <<v <- binary_part(pixels, row * width, width)>>,
        into: <<>>,
        do: <<elem(lut, v)::signed-8>>
    end
  end

  defp trinary(v, %{negate: negate, occupied: occ, free: free}) do
    p = if negate == 1, do: v / 255, else: (255 - v) / 255

    cond do
      p > occ -> 100
      p < free -> 0
      true -> -1
    end
  end
end
